"""The closed loop's statistics over a seeded cohort (in process, deterministic).

Over the paper's two options (its kernel) and three (the general form), one loop: the same
statistics hold, and the general form on the paper's schedule is the paper's session.
"""

from collections import Counter

import pytest

from services.model.closed_loop import run_offline_session
from services.model.params import NodConfig
from services.model.schedule import OptionsSchedule


@pytest.fixture(scope="module", params=[2, 3], ids=["2 options", "3 options"])
def cohort(request):
    cfg = NodConfig()
    schedule = None if request.param == 2 else OptionsSchedule.default(request.param)
    return [run_offline_session(cfg, seed, cohort=True, schedule=schedule) for seed in range(10)]


@pytest.mark.parametrize("schedule", [None, OptionsSchedule.default(3)], ids=["2", "3"])
def test_offline_session_is_reproducible(schedule):
    cfg = NodConfig()
    assert run_offline_session(cfg, 5, schedule=schedule) == run_offline_session(
        cfg, 5, schedule=schedule)


@pytest.mark.parametrize("seed", [0, 3, 11])
def test_the_general_form_on_the_papers_schedule_is_the_papers_session(seed):
    """`OptionsSchedule.default(2)` (red, blue: option 0 red) through the N-option parts gives
    the kernel's session: the same presses, outcomes, times and hand and arm paths."""
    cfg = NodConfig()
    schedule = OptionsSchedule.default(2)
    paper = run_offline_session(cfg, seed, cohort=True, record=True)
    general = run_offline_session(cfg, seed, cohort=True, record=True, schedule=schedule)
    assert len(paper) == len(general) == 8
    for p, g in zip(paper, general, strict=True):
        named = (schedule.name(g.option), schedule.name(g.human), schedule.name(g.robot))
        assert (p.option, p.human, p.robot) == named
        assert (p.trial, p.mode, p.outcome, p.switches, p.violations, p.score) == (
            g.trial, g.mode, g.outcome, g.switches, g.violations, g.score)
        assert (p.duration_s, p.press_s, p.attempts) == (g.duration_s, g.press_s, g.attempts)
        paths = [[(s.t_ns, s.hand_x, s.hand_y, s.ee_x, s.ee_y) for s in t.samples]
                 for t in (p, g)]
        assert paths[0] == paths[1] and len(paths[0]) > 10
        assert all(s.z_h is None for s in g.samples)  # a vector has no scalar column


def test_dissensus_trials_end_in_dissensus(cohort):
    outcomes = Counter(t.outcome for session in cohort for t in session[:3])
    assert (outcomes["D"] + outcomes["DH"]) / sum(outcomes.values()) >= 0.8
    for session in cohort:
        for t in session[:3]:
            assert t.option is None and t.mode == "dissensus"


def test_consensus_trials_reach_consensus_on_the_option(cohort):
    later = [t for session in cohort for t in session[3:]]
    # The robot ends on O unless a participant heading straight for O presses faster than the
    # requirement b* was derived for (2.2 s after go; services/analysis/bstar.py).
    assert sum(t.robot == t.option for t in later) / len(later) >= 0.8
    assert sum(t.outcome in ("C", "CH") for t in later) / len(later) >= 0.6
    # Trust grows with the gaze's strength: the last trial agrees at least as often as the 4th.
    c4 = sum(s[3].outcome == "C" for s in cohort)
    c8 = sum(s[7].outcome == "C" for s in cohort)
    assert c8 >= c4


def test_scores_stay_in_the_papers_range(cohort):
    for session in cohort:
        total = sum(t.score for t in session)
        violations = sum(t.violations for t in session)
        assert -8 - violations <= total <= 16
