"""The judge's verdict over N options (services/model/judge.py, SPEC §6 over N_o options).

Outcomes C / CH / D / DH from the switches of ẑ_h's leading option and whether both pressed
the same box; a timeout (a press seen after it is not the person's choice); a robot that did not
press; control trials by agreement; violations; ẑ_h counted up to and including the press.
Expected values are worked from the rules, not read back from the judge.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.geometry import Colour, OptionsLayout, TableLayout
from services.model.judge import OptionsTrialJudge, TrialJudge
from services.model.params import NodConfig
from services.model.protocol import TrialEnd

CFG = NodConfig()
C_MAX = CFG.debounce.c_max  # 4
BEFORE = (0.5, 0.8)  # the participant's side of the default commit line (y = 0.45)
AFTER = (0.5, 0.3)  # past it
TARGET = CFG.protocol.target_clicks  # 10


def lead(j: int, n: int) -> np.ndarray:
    """A ẑ_h that leads option j by 2 (half-lead 1, beyond the 0.5 switch dead band)."""
    z = np.zeros(n)
    z[j] = 2.0
    return z


def judge(n: int = 3, mode: str = "consensus", labels: str = "agreement") -> OptionsTrialJudge:
    cfg = replace(CFG, protocol=replace(CFG.protocol, control_labels=labels))
    return OptionsTrialJudge(cfg, OptionsLayout.row(n), mode)  # type: ignore[arg-type]


def feed(j: OptionsTrialJudge, leaders: list[int], centers=None, t0: float = 0.0) -> float:
    """Observe one ẑ_h per leader, 0.1 s apart; returns the time of the last one."""
    n = j.layout.n_options
    t = t0
    for i, k in enumerate(leaders):
        t = t0 + 0.1 * i
        j.observe(lead(k, n), BEFORE if centers is None else centers[i], t)
    return t


def press(j: OptionsTrialJudge, box: int, t: float) -> None:
    assert j.see_hand([j.layout.boxes[box].center], t) == box and j.t_press == t


def expected_score(same: bool, clicks: int | None, violations: int) -> int:
    """SPEC §6 by hand: +1 same box, +1 exactly the target clicks, −1 if either failed,
    −1 per violation."""
    counter_failed = clicks is not None and clicks != TARGET
    return (int(same) + int(clicks == TARGET) - int(not same or counter_failed)
            - violations)


# -- hand-worked trials --------------------------------------------------------------------


def test_no_switch_same_box_is_C_different_is_D():
    for human, robot, outcome, score in ((1, 1, "C", 2), (1, 2, "D", 0)):
        j = judge()
        t = feed(j, [1] * 6)
        press(j, human, t)
        v = j.verdict(TrialEnd(True, True, t + 1), robot, 10)
        assert (v.human, v.robot, v.outcome, v.switches, v.violations, v.score) == (
            human, robot, outcome, 0, 0, score)


def test_one_switch_same_box_is_CH_different_is_DH():
    leaders = [0] * 3 + [2] * C_MAX  # led option 0, then C_MAX samples of 2: one switch
    for human, robot, outcome, score in ((2, 2, "CH", 2), (2, 0, "DH", 0)):
        j = judge()
        t = feed(j, leaders)
        press(j, human, t)
        v = j.verdict(TrialEnd(True, True, t + 1), robot, 10)
        assert (v.outcome, v.switches, v.violations, v.score) == (outcome, 1, 0, score)


def test_a_run_shorter_than_c_max_is_no_switch_and_a_third_option_restarts_it():
    j = judge(4)
    # 0 leads; 1 for C_MAX−1 samples, then 2 for C_MAX−1, then 1 again for C_MAX−1: never
    # C_MAX in a row of one option, so no switch.
    feed(j, [0] * 2 + [1] * (C_MAX - 1) + [2] * (C_MAX - 1) + [1] * (C_MAX - 1))
    assert j.tracker.switches == 0 and j.tracker.first == 0


def test_a_second_switch_and_a_switch_past_the_commit_line_are_violations():
    j = judge()
    t = feed(j, [0] * 2 + [1] * C_MAX + [2] * C_MAX)  # two switches: the second is a violation
    press(j, 2, t)
    v = j.verdict(TrialEnd(True, True, t + 1), 2, 10)
    assert (v.outcome, v.switches, v.violations, v.score) == ("CH", 2, 1, 1)

    late = judge()
    leaders = [0] * 3 + [1] * C_MAX
    centers = [BEFORE] * 3 + [AFTER] * C_MAX  # the hand crossed as the switch began
    t = feed(late, leaders, centers)
    press(late, 1, t)
    v = late.verdict(TrialEnd(True, True, t + 1), 1, 10)
    assert (v.outcome, v.switches, v.violations, v.score) == ("CH", 1, 1, 1)


def test_a_near_tie_carries_no_option():
    j = judge()
    for i in range(10):  # options 0 and 1 within the dead band (half-lead 0.4 ≤ 0.5)
        j.observe(np.array([1.0, 0.2, 0.0]) if i % 2 else np.array([0.2, 1.0, 0.0]), BEFORE, i)
    assert j.tracker.first is None and j.tracker.switches == 0


def test_a_press_after_the_timeout_is_not_the_persons_choice():
    j = judge()
    t = feed(j, [1] * 6)
    press(j, 1, t + 5.0)  # the hand reaches a box while the arm presses after the timeout
    v = j.verdict(TrialEnd(False, True, t + 6.0), 1, 10)  # the protocol: a timeout
    assert v.human is None and v.outcome is None
    assert v.score == 0  # not the same box: +1 counter −1 failure
    assert j.verdict(TrialEnd(True, True, t + 6.0), 1, 10).human == 1  # had it been in time


def test_a_timeout_without_any_press():
    j = judge()
    feed(j, [0] * 2 + [1] * C_MAX)
    v = j.verdict(TrialEnd(False, True, 11.0), 1, None)
    assert (v.human, v.outcome, v.switches, v.violations, v.score) == (None, None, 1, 0, -1)


def test_a_robot_that_did_not_press_has_no_outcome_and_scores_as_different():
    j = judge()
    t = feed(j, [1] * 6)
    press(j, 1, t)
    v = j.verdict(TrialEnd(True, False, t + 3.0), None, 10)
    assert (v.human, v.robot, v.outcome, v.score) == (1, None, None, 0)


def test_control_trials_are_labelled_by_agreement_unless_the_protocol_says_switches():
    leaders = [0] * 3 + [1] * C_MAX  # one switch
    got = {}
    for mode, labels in (("dissensus", "agreement"), ("dissensus", "switches"),
                         ("consensus", "agreement")):
        for robot in (1, 2):
            j = judge(3, mode, labels)
            t = feed(j, leaders)
            press(j, 1, t)
            v = j.verdict(TrialEnd(True, True, t + 1), robot, 10)
            assert v.switches == 1  # counted whatever the label
            got[mode, labels, robot] = v.outcome
    assert got == {
        ("dissensus", "agreement", 1): "C", ("dissensus", "agreement", 2): "D",
        ("dissensus", "switches", 1): "CH", ("dissensus", "switches", 2): "DH",
        ("consensus", "agreement", 1): "CH", ("consensus", "agreement", 2): "DH",
    }


def test_the_press_poses_own_z_hat_counts_and_nothing_after_it():
    # ẑ_h is stamped with its pose's time, so the press pose's ẑ_h arrives after the press
    # with t == t_press: it counts. Here it is the C_MAX-th sample of option 2: a switch.
    def with_last(after_press: float) -> OptionsTrialJudge:
        j = judge()
        t = feed(j, [0] * 3 + [2] * (C_MAX - 1))
        press(j, 2, t + 0.1)
        j.observe(lead(2, 3), BEFORE, t + 0.1 + after_press)
        return j

    at = with_last(0.0)
    assert at.tracker.switches == 1
    assert at.verdict(TrialEnd(True, True, 2.0), 2, 10).outcome == "CH"
    after = with_last(1e-9)
    assert after.tracker.switches == 0
    assert after.verdict(TrialEnd(True, True, 2.0), 2, 10).outcome == "C"


# -- properties ----------------------------------------------------------------------------


@st.composite
def segments(draw, n: int) -> list[tuple[int, int]]:
    """Runs (option, length) of ẑ_h's leading option, each a different option from the last."""
    out: list[tuple[int, int]] = []
    for _ in range(draw(st.integers(1, 6))):
        option = draw(st.integers(0, n - 1).filter(lambda o: not out or o != out[-1][0]))
        out.append((option, draw(st.integers(1, 2 * C_MAX))))
    return out


def switches_of(runs: list[tuple[int, int]]) -> int:
    """By the rule: a run of C_MAX or more samples of an option other than the leader."""
    leader, switches = runs[0][0], 0
    for option, length in runs[1:]:
        if option != leader and length >= C_MAX:
            leader, switches = option, switches + 1
    return switches


@settings(max_examples=200, deadline=None)
@given(
    st.integers(2, 5).flatmap(lambda n: st.tuples(
        st.just(n),
        segments(n),
        st.one_of(st.none(), st.integers(0, n - 1)),  # the box the hand reached (None: never)
        st.one_of(st.none(), st.integers(0, n - 1)),  # the robot's box (None: did not press)
        st.booleans(),  # whether the protocol counted the human's press (False: a timeout)
        st.sampled_from([None, TARGET - 1, TARGET, TARGET + 3]),
        st.sampled_from(["consensus", "dissensus"]),
    ))
)
def test_the_verdict_follows_the_rules(case):
    n, runs, hand, robot, in_time, clicks, mode = case
    j = judge(n, mode)
    t = feed(j, [o for o, length in runs for _ in range(length)])
    if hand is not None:
        press(j, hand, t)
    end = TrialEnd(in_time, robot is not None, t + 1.0)
    v = j.verdict(end, robot, clicks)

    switches = switches_of(runs)
    violations = max(0, switches - 1)  # the hand never crossed the commit line here
    human = hand if in_time else None  # a press after the timeout is not the person's
    same = human is not None and human == robot
    if human is None or robot is None:
        outcome = None
    elif mode == "dissensus":  # control trials by agreement (the default rule)
        outcome = "C" if same else "D"
    else:
        outcome = ("C" if same else "D") if switches == 0 else ("CH" if same else "DH")
    assert (v.human, v.robot, v.outcome, v.switches, v.violations) == (
        human, robot, outcome, switches, violations)
    assert v.score == expected_score(same, clicks, violations)
    # What the judge saw without the protocol's word (end=None): the hand's box as pressed.
    assert j.verdict(None, robot, clicks).human == hand


# -- the two-option kernel ------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(st.sampled_from([-2.0, -0.6, -0.5, -0.1, 0.0, 0.3, 0.5, 1.5]),
                       st.sampled_from([BEFORE, AFTER, None])), min_size=1, max_size=40),
    st.sampled_from([None, "red", "blue"]),  # the box the hand reached (None: never)
    st.sampled_from([None, "red", "blue"]),  # the robot's box
    st.booleans(),  # the protocol counted the press in time
    st.sampled_from([None, TARGET - 1, TARGET]),
    st.sampled_from(["consensus", "dissensus"]),
    st.sampled_from(["agreement", "switches"]),
)
def test_two_boxes_the_general_judge_gives_the_papers_verdict(
    stream, hand: Colour | None, robot: Colour | None, in_time: bool, clicks, mode, labels
):
    # The paper's TrialJudge (ẑ_h a number) and the general one fed ẑ_h = (x, −x) on the
    # paper's table: the same verdict, red as option 0 (the dead band 0.5 lands on ±0.5).
    cfg = replace(CFG, protocol=replace(CFG.protocol, control_labels=labels))
    table = TableLayout()
    paper = TrialJudge(cfg, table, mode)
    general = OptionsTrialJudge(cfg, OptionsLayout.from_table(table), mode)
    index = {"red": 0, "blue": 1, None: None}
    for i, (z, center) in enumerate(stream):
        paper.observe(z, center, 0.1 * i)
        general.observe(np.array([z, -z]), center, 0.1 * i)
    t = 0.1 * len(stream)
    if hand is not None:
        box = table.red if hand == "red" else table.blue
        assert paper.see_hand([box.center], t) == hand
        assert general.see_hand([box.center], t) == index[hand]
    end = TrialEnd(in_time, robot is not None, t + 1.0)
    want = paper.verdict(end, robot, clicks)
    got = general.verdict(end, index[robot], clicks)
    assert (got.human, got.robot) == (index[want.human], index[want.robot])
    assert (got.outcome, got.switches, got.violations, got.score) == (
        want.outcome, want.switches, want.violations, want.score)
    assert general.tracker.samples == paper.tracker.samples
