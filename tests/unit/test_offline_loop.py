"""The closed loop's statistics over a seeded cohort (in process, deterministic)."""

from collections import Counter

import pytest

from services.model.closed_loop import run_offline_session
from services.model.params import NodConfig


@pytest.fixture(scope="module")
def cohort():
    cfg = NodConfig()
    return [run_offline_session(cfg, seed, cohort=True) for seed in range(10)]


def test_offline_session_is_reproducible():
    cfg = NodConfig()
    assert run_offline_session(cfg, 5) == run_offline_session(cfg, 5)


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
