"""`judge_trial`, what the conductor and the offline loop store for a finished trial (SPEC §6).

Every branch worked by hand: who pressed (human and robot, either missing), C / CH / D / DH,
violations, the score with and without the operator's clicks; and a timeout — the human never
pressed — that must have no outcome class, so that it never enters the study's tables.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.analysis.study import load_study
from services.model.closed_loop import OfflineTrial
from services.model.debounce import DebounceParams
from services.model.geometry import CommitLine, Point
from services.model.outcome import OutcomeTracker, judge_trial
from services.model.schedule import TrialSpec
from services.sim.cohort import offline_record
from services.store import Store, TrialRecord

BEFORE: Point = (0.5, 0.8)  # the participant's side of the default commit line (y = 0.45)
AFTER: Point = (0.5, 0.3)  # past it
STRAIGHT = [0.0, 0.0, 1.0, 1.0, 1.0, 1.0]  # heads for red from the start: no switch
ONE_SWITCH = [1.0, 1.0, -1.0, -1.0, -1.0, -1.0]  # red, then 4 samples of blue: one switch
TWO_SWITCHES = ONE_SWITCH + [1.0] * 4  # and back to red: the second switch is a violation


def tracked(z_hats: Sequence[float], centers: Sequence[Point | None] | None = None):
    tracker = OutcomeTracker(DebounceParams(c_max=4), CommitLine())
    for z, c in zip(z_hats, centers or [BEFORE] * len(z_hats), strict=True):
        tracker.add(z, c)
    return tracker


def judged(z_hats, human, robot, clicks=10, centers=None, target=10):
    j = judge_trial(tracked(z_hats, centers), human, robot, clicks, target)
    return (j.outcome, j.switches, j.violations, j.score)


@pytest.mark.parametrize(
    ("z_hats", "human", "robot", "expected"),
    [
        # (outcome, switches, violations, score); score = buzzer + counter + failure − violations
        (STRAIGHT, "red", "red", ("C", 0, 0, 2)),  # 1 + 1 + 0
        (STRAIGHT, "blue", "blue", ("C", 0, 0, 2)),
        (STRAIGHT, "red", "blue", ("D", 0, 0, 0)),  # 0 + 1 − 1
        (ONE_SWITCH, "blue", "blue", ("CH", 1, 0, 2)),  # one early switch is allowed
        (ONE_SWITCH, "blue", "red", ("DH", 1, 0, 0)),
        (TWO_SWITCHES, "red", "red", ("CH", 2, 1, 1)),  # 1 + 1 + 0 − 1
        (TWO_SWITCHES, "red", "blue", ("DH", 2, 1, -1)),  # 0 + 1 − 1 − 1
    ],
)
def test_both_pressed_classifies_and_scores(z_hats, human, robot, expected):
    assert judged(z_hats, human, robot) == expected


def test_a_switch_after_the_commit_line_is_a_violation_and_costs_a_point():
    centers = [BEFORE, AFTER] + [AFTER] * 4  # crossed at sample 1; the switch's onset is 2
    assert judged(ONE_SWITCH, "blue", "blue", centers=centers) == ("CH", 1, 1, 1)


@pytest.mark.parametrize(
    ("clicks", "target", "same", "score"),
    [
        (10, 10, True, 2),  # both tasks done
        (9, 10, True, 0),  # counter failed: one done, one not
        (None, 10, True, 1),  # counter not entered: unknown, neither a point nor a failure
        (10, 10, False, 0),  # different buzzer: one done, one not
        (11, 10, False, -1),  # neither done: −1, not −2
        (None, 10, False, -1),
        (12, 12, True, 2),  # the target is the protocol's, not a constant
        (10, 12, True, 0),
    ],
)
def test_the_score_counts_the_operators_clicks(clicks, target, same, score):
    robot = "red" if same else "blue"
    assert judged(STRAIGHT, "red", robot, clicks, target=target)[3] == score


@pytest.mark.parametrize(
    ("z_hats", "switches", "violations", "score"),
    [([], 0, 0, 0), (STRAIGHT, 0, 0, 0), (ONE_SWITCH, 1, 0, 0), (TWO_SWITCHES, 2, 1, -1)],
)
def test_a_timeout_has_no_outcome_class_but_keeps_its_switches(z_hats, switches, violations, score):
    # The human never pressed: not "D" (nor "DH"), whatever the path; it scores as a different
    # buzzer (0 + 1 − 1, the clicks right), and its switches and violations stay on record.
    j = judge_trial(tracked(z_hats), None, "red", 10, 10)
    assert j.outcome is None and j.human is None and j.robot == "red"
    assert (j.switches, j.violations, j.score) == (switches, violations, score)


@pytest.mark.parametrize("human", ["red", "blue", None])
def test_a_trial_the_robot_did_not_press_has_no_outcome_and_scores_as_different(human):
    j = judge_trial(tracked(STRAIGHT), human, None, 10, 10)
    assert (j.outcome, j.human, j.robot, j.score) == (None, human, None, 0)
    assert judge_trial(tracked(STRAIGHT), human, None, None, 10).score == -1


@pytest.mark.parametrize(
    ("z_hats", "switches", "violations", "score"),
    [(STRAIGHT, 0, 0, 0), (ONE_SWITCH, 1, 0, 0), (TWO_SWITCHES, 2, 1, -1)],
)
def test_a_trial_the_robot_did_not_press_keeps_the_humans_switches(
    z_hats, switches, violations, score
):
    # SPEC §6: switches and violations are counted and stored for every trial; the violations
    # are the person's and cost their point whatever the arm did.
    j = judge_trial(tracked(z_hats), "red", None, 10, 10)
    assert (j.outcome, j.switches, j.violations, j.score) == (None, switches, violations, score)


@settings(max_examples=200, deadline=None)
@given(
    z_hats=st.lists(st.sampled_from([-1.0, 0.0, 1.0]), max_size=30),
    human=st.sampled_from(["red", "blue", None]),
    robot=st.sampled_from(["red", "blue"]),
    clicks=st.one_of(st.none(), st.integers(0, 20)),
)
def test_the_judgement_is_the_classification_and_the_score_formula(z_hats, human, robot, clicks):
    result = tracked(z_hats).result(human, robot)
    j = judge_trial(tracked(z_hats), human, robot, clicks, 10)
    same = human == robot
    kind = ("C" if same else "D") + ("H" if result.switches else "")
    assert j.outcome == (kind if human is not None else None)
    failed = not same or (clicks is not None and clicks != 10)
    assert j.score == same + (clicks == 10) - failed - result.violations
    assert (j.switches, j.violations) == (result.switches, result.violations)


def _record(trial: int, human, robot, z_hats) -> TrialRecord:
    """Trial `trial` of the paper's schedule (1-3 control, then consensus on red), judged as the
    conductor judges it and stored as the cohort stores a simulated trial."""
    j = judge_trial(tracked(z_hats), human, robot, 10, 10)
    spec = TrialSpec(trial, "dissensus") if trial <= 3 else TrialSpec(trial, "consensus", "red")
    result = OfflineTrial(
        trial, spec.mode, spec.option, j.human, j.robot, j.outcome, j.switches, j.violations,
        j.score, duration_s=5.0,
    )
    return offline_record(result, spec, trial * 10**10)


def test_a_timeout_never_enters_the_study_statistics(tmp_path: Path):
    # P01 and P02 both: control trials D, experiment trials C; P01's trial 5 times out after a
    # switch (a tracker would call it "DH"). It must be excluded: counted as `none`, out of the
    # 4→5 and 5→6 tables, and out of P01's experiment category.
    store = Store(tmp_path / "s.sqlite")
    for n, pid in enumerate(("P01", "P02")):
        sid = f"s{n}"
        store.begin_session(sid, pid, "sim", n, 0, {})
        for trial in range(1, 9):
            if trial <= 3:
                rec = _record(trial, "blue", "red", STRAIGHT)
            elif pid == "P01" and trial == 5:
                rec = _record(trial, None, "red", ONE_SWITCH)
            else:
                rec = _record(trial, "red", "red", STRAIGHT)
            store.write_trial(sid, rec, [])
        store.finish_session(sid, 10**12)
    store.close()
    doc = load_study(str(tmp_path / "s.sqlite"))
    assert doc["excluded_trials"] == [{"participant": "P01", "trial": 5, "reason": "timeout"}]
    assert doc["grid"]["P01"] == ["D"] * 3 + ["C", None, "C", "C", "C"]
    row = doc["frequencies"]["5"]
    assert (row["C"], row["CH"], row["D"], row["DH"], row["none"]) == (1, 0, 0, 0, 1)
    for pair in ("trial_4_vs_5", "trial_5_vs_6"):
        table = doc["stuart_maxwell"][pair]["table"]
        assert doc["stuart_maxwell"][pair]["n"] == 1 and table[0][0] == 1, pair  # P02's C→C
    assert doc["stuart_maxwell"]["trial_6_vs_7"]["n"] == 2
    assert doc["phase_categories"]["P01"] == {"control": "D", "experiment": "C"}
    assert doc["contingency"]["table"][2][0] == 2  # both participants D → C
