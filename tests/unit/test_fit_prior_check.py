"""The out-of-prior check on data whose population is known: false alarms, power, invariances."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from services.fit.prior_check import ALPHA, PriorCheck


def _people(n: int, seed: int, shift: float = 0.0, dims: int = 8) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = rng.normal(shift, 1.0, (n, dims))
    x[:, 0] = np.exp(x[:, 0])  # a skewed summary, as press times are
    x[rng.random(n) < 0.1, 1] = np.nan  # missing now and then, as a timeout leaves
    return x


def test_people_of_the_prior_are_flagged_about_alpha_of_the_time_others_mostly():
    check = PriorCheck.train(_people(800, 1), _people(400, 2))
    fresh = check.outside(_people(3000, 3))
    assert 0.02 <= fresh.mean() <= 0.085  # at most ALPHA, up to the calibration's own draw
    assert check.outside(_people(500, 4, shift=2.0)).mean() > 0.9
    assert check.outside(_people(500, 4, shift=1.0)).mean() > 0.3  # nearer: fewer
    p = check.p_value(_people(3000, 3))
    assert np.all((p > 0) & (p <= 1))
    assert abs(np.mean(p < 0.5) - 0.5) < 0.06  # p-values of the prior's people: ~uniform


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.1, 3.0))
def test_the_check_reads_ranks_so_a_monotone_rescaling_of_a_summary_changes_nothing(seed, power):
    """exp(), a power, a unit change: the same order of people, the same p-values."""
    ref, held, test = _people(200, seed), _people(100, seed + 1), _people(60, seed + 2)
    p = PriorCheck.train(ref, held).p_value(test)

    def rescale(x: np.ndarray) -> np.ndarray:
        y = x.copy()
        y[:, 0] = 1000.0 * y[:, 0] ** power  # column 0 is positive
        y[:, 3] = np.exp(y[:, 3])
        return y

    q = PriorCheck.train(rescale(ref), rescale(held)).p_value(rescale(test))
    assert np.allclose(p, q)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_a_larger_score_never_has_a_larger_p_value(seed):
    check = PriorCheck.train(_people(150, seed), _people(80, seed + 1))
    test = _people(100, seed + 2, shift=0.5)
    s, p = check.score(test), check.p_value(test)
    order = np.argsort(s)
    assert np.all(np.diff(p[order]) <= 1e-12)
    assert np.array_equal(check.outside(test), p < ALPHA)
