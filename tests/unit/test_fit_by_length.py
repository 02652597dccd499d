"""The estimate as the session goes: after k trials, from those trials only (`ByLength`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.fit.estimator import ByLength, QuantileEstimator, estimate_after
from services.model.geometry import TableLayout
from services.model.summaries import (
    TRIALS,
    TrialPath,
    first_trials,
    summarise,
    summary_names,
)

NAMES = summary_names()
COL = {n: i for i, n in enumerate(NAMES)}


def _table(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """People whose every trial shows `speed` through noise, a summary vector per person.

    Each trial's hand speed and onset is one noisy reading of the person's parameter; the
    phase and session summaries are taken by `first_trials` at 8, as from a real session.
    """
    rng = np.random.default_rng(seed)
    theta = rng.uniform(0.2, 0.5, (n, 1))
    x = np.full((n, len(NAMES)), np.nan)
    for k in TRIALS:
        x[:, COL[f"speed_{k}"]] = theta[:, 0] + rng.normal(0, 0.15, n)
        x[:, COL[f"onset_{k}"]] = 0.3 + rng.normal(0, 0.05, n)
        x[:, COL[f"switch_{k}"]] = 0.0
    return theta, first_trials(x, len(TRIALS))


@pytest.fixture(scope="module")
def trained() -> tuple[ByLength, np.ndarray, np.ndarray]:
    theta, x = _table(1000, 1)
    return ByLength(("speed",), seed=0).train(theta, x), theta, x


def test_first_trials_blanks_later_trials_and_keeps_a_whole_session():
    _, x = _table(5, 2)
    assert np.array_equal(first_trials(x, 8), x, equal_nan=True)
    cut = first_trials(x, 3)
    assert np.isnan(cut[:, COL["speed_4"]]).all() and np.isnan(cut[:, COL["speed_8"]]).all()
    assert np.array_equal(cut[:, COL["speed_3"]], x[:, COL["speed_3"]])
    # The phase's median is over the trials played: the control trials, and no consensus one.
    want = np.median(x[:, [COL[f"speed_{k}"] for k in (1, 2, 3)]], axis=1)
    assert np.allclose(cut[:, COL["speed_control"]], want)
    assert np.isnan(cut[:, COL["speed_consensus"]]).all()
    with pytest.raises(ValueError):
        first_trials(x, 0)


def test_at_eight_trials_it_is_the_complete_session_estimator(trained):
    by_length, theta, x = trained
    whole = QuantileEstimator(("speed",), seed=0).train(theta, x)
    fresh_theta, fresh = _table(200, 3)
    a, b = by_length.predict(8, fresh), whole.predict(fresh)
    assert np.array_equal(a.estimate, b.estimate) and np.array_equal(a.low, b.low)
    assert np.array_equal(a.high, b.high)
    assert by_length.at[8].check[0].coverage == whole.check[0].coverage


@settings(max_examples=5, deadline=None)
@given(st.integers(4, 10**6))
def test_the_intervals_hold_at_every_length_and_narrow_as_trials_come(trained, seed):
    """On any 400 new people of the prior: 90 % coverage at each k, wider with fewer trials."""
    by_length, _, _ = trained
    fresh_theta, fresh = _table(400, seed)
    widths = []
    for k in TRIALS:
        fit = by_length.predict(k, fresh)
        inside = (fit.low[:, 0] <= fresh_theta[:, 0]) & (fresh_theta[:, 0] <= fit.high[:, 0])
        assert 0.82 <= inside.mean() <= 0.98, k  # 0.86-0.96 on 40 draws
        widths.append(float(np.mean(fit.high[:, 0] - fit.low[:, 0])))
    # On average wider with fewer trials: each trial is one more reading of the speed.
    assert widths[0] > widths[3] > widths[7]
    assert all(a >= b * 0.97 for a, b in zip(widths, widths[1:], strict=False))


def _session(rng: np.random.Generator) -> list[TrialPath]:
    """Eight trials of a hand moving right at a drawn speed (1-3 control, 4-8 consensus)."""
    out = []
    for k in TRIALS:
        v = rng.uniform(0.2, 0.5)
        t = tuple(float(s) for s in np.arange(0, 2.0, 1 / 30))
        out.append(TrialPath(k, "dissensus" if k <= 3 else "consensus", 0.0 if k <= 3 else 1.0,
                             None, None, 0, False, t,
                             tuple(0.5 + v * max(0.0, s - 0.3) for s in t),
                             tuple(0.8 for _ in t)))
    return out


@settings(max_examples=8, deadline=None)
@given(st.integers(1, 7), st.integers(0, 10**6))
def test_after_k_trials_only_those_trials_count(trained, k, seed):
    by_length, _, _ = trained
    rng = np.random.default_rng(seed)
    session = _session(rng)
    layout = TableLayout()
    before = estimate_after(by_length, k, session, layout)
    later = session[k]  # trial k + 1: another hand, or interrupted, or not there at all
    changed = [*session[:k], dataclasses.replace(later, x=tuple(1.0 - v for v in later.x),
                                                 interrupted=bool(seed % 2))]
    for other in (changed, session[:k]):
        after = estimate_after(by_length, k, other, layout)
        assert np.array_equal(before.estimate, after.estimate)
        assert np.array_equal(before.low, after.low) and np.array_equal(before.high, after.high)
    assert before.estimate.shape == (1, 1)
    assert before.low[0, 0] <= before.estimate[0, 0] <= before.high[0, 0]
    # What it reads is the first k trials' summaries, as `summarise` reads them.
    assert np.array_equal(first_trials(summarise(session[:k], layout), k),
                          first_trials(summarise(session, layout), k), equal_nan=True)


def test_a_simulated_session_cut_to_k_trials_reads_as_its_first_k_trials():
    """`first_trials` of a whole session = `summarise` of its first k trials (but late_turns)."""
    from services.cohort.person import load_cohort_params
    from services.fit.prior import load_prior
    from services.fit.simulate import Population
    from services.model.summaries import from_offline

    pop = Population(load_cohort_params(None), load_prior(None))
    paths = from_offline(pop.session(3))
    whole = summarise(paths, pop.cfg.layout)
    late = COL["late_turns"]
    for k in TRIALS:
        cut, played = first_trials(whole, k), summarise(paths[:k], pop.cfg.layout)
        keep = np.arange(len(NAMES)) != late
        assert np.array_equal(cut[keep], played[keep], equal_nan=True), k
        assert np.isnan(cut[late]) if k < 8 else cut[late] == whole[late]
