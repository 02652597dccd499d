"""Participant scoring (SPEC §6, paper Sec 3.2 Steps 4 and 6)."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.model.scoring import TrialScore, score_range, score_trial, session_score


@pytest.mark.parametrize(
    ("same", "clicks", "violations", "total"),
    [
        (True, 10, 0, 2),  # both tasks
        (True, 9, 0, 0),  # buzzer only
        (False, 10, 0, 0),  # counter only
        (False, 11, 0, -1),  # neither
        (True, None, 0, 1),  # counter not entered: unknown, neither point nor failure
        (False, None, 0, -1),
        (True, 10, 1, 1),
        (True, 10, 3, -1),
        (False, 0, 2, -3),
    ],
)
def test_score_table(same: bool, clicks: int | None, violations: int, total: int) -> None:
    s = score_trial(same, clicks, violations)
    assert s.total == total
    assert s.counter_known == (clicks is not None)
    assert s.penalty == -violations


def test_parts() -> None:
    assert score_trial(True, 10) == TrialScore(1, 1, 0, 0, True)
    assert score_trial(False, 3, 1) == TrialScore(0, 0, -1, -1, True)
    assert score_trial(True, 7, target_clicks=7).total == 2


def test_validation() -> None:
    with pytest.raises(ValueError):
        score_trial(True, -1)
    with pytest.raises(ValueError):
        score_trial(True, 10, violations=-1)
    with pytest.raises(ValueError):
        score_trial(True, 10, target_clicks=0)
    with pytest.raises(ValueError):
        score_range(-1)


def test_paper_range_over_8_trials_without_violations() -> None:
    assert score_range(8) == (-8, 16)
    per_trial = {score_trial(same, c).total for same in (True, False) for c in (10, 9, None)}
    assert min(per_trial) == -1 and max(per_trial) == 2
    best = session_score([score_trial(True, 10)] * 8)
    worst = session_score([score_trial(False, 0)] * 8)
    assert (worst, best) == score_range(8)


@given(
    trials=st.lists(
        st.tuples(st.booleans(), st.one_of(st.none(), st.integers(0, 20))), min_size=8, max_size=8
    )
)
def test_any_session_without_violations_is_in_range(
    trials: list[tuple[bool, int | None]],
) -> None:
    total = session_score(score_trial(same, clicks) for same, clicks in trials)
    lo, hi = score_range(8)
    assert lo <= total <= hi


def test_session_total_is_the_sum() -> None:
    scores = [score_trial(s, c, v) for s, c, v in itertools.product((True, False), (10, 5), (0, 1))]
    assert session_score(scores) == sum(s.total for s in scores) == 2 + 1 + 0 - 1 + 0 - 1 - 1 - 2
