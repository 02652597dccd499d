"""The estimator and the recovery metrics on synthetic data, where the truth is known."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from services.fit.estimator import Estimates, ModelClassifier, QuantileEstimator
from services.fit.report import parameter_cell
from services.model.recovery import (
    Recovery,
    bootstrap_correlation,
    correlation,
    recovery,
    recovery_intervals,
    wilson,
)


def _synthetic(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Two parameters: `planted` shows in the summaries (with noise), `hidden` does not."""
    rng = np.random.default_rng(seed)
    theta = np.column_stack([rng.uniform(0, 1, n), rng.uniform(0, 1, n)])
    noise = rng.normal(0, 0.05, (n, 3))
    summaries = np.column_stack([
        theta[:, 0] + noise[:, 0],
        np.exp(theta[:, 0]) + noise[:, 1],
        noise[:, 2],  # nothing of either parameter
    ])
    summaries[rng.random(n) < 0.1, 1] = np.nan  # missing summaries, as a timeout leaves
    return theta, summaries


def test_the_estimator_recovers_a_planted_parameter_and_flags_a_hidden_one():
    theta, summaries = _synthetic(1000, 1)
    est = QuantileEstimator(("planted", "hidden"), seed=0).train(theta, summaries)
    planted, hidden = est.check
    assert planted.identifiable and planted.correlation > 0.95
    assert not hidden.identifiable  # coverage fine, but nothing to correlate with
    # Fresh people from the same prior: estimates near the truth, 90 % intervals cover ~90 %.
    fresh_theta, fresh = _synthetic(600, 2)
    fit = est.predict(fresh)
    r = recovery("planted", fresh_theta[:, 0], fit.estimate[:, 0], fit.low[:, 0], fit.high[:, 0])
    assert r.correlation > 0.95 and abs(r.bias) < 0.02
    assert 0.84 <= r.coverage <= 0.96
    width = np.median(fit.high[:, 0] - fit.low[:, 0])
    assert width < 0.3  # informative: the prior's own 90 % interval is 0.9 wide
    h = recovery("hidden", fresh_theta[:, 1], fit.estimate[:, 1], fit.low[:, 1], fit.high[:, 1])
    assert 0.84 <= h.coverage <= 0.96  # honest: wide intervals, still calibrated
    assert np.all(fit.low <= fit.estimate) and np.all(fit.estimate <= fit.high)


def test_the_gaze_classifier_tells_two_models_apart_only_when_they_differ():
    rng = np.random.default_rng(3)
    with_gaze = rng.normal(1.0, 1.0, (400, 2))
    without = rng.normal(0.0, 1.0, (400, 2))
    clf = ModelClassifier().train(with_gaze[:300], without[:300])
    assert clf.accuracy(with_gaze[300:], without[300:]) > 0.7  # Bayes rate ≈ 0.76
    # Two labels of one model: nothing to learn, held-out accuracy near a coin's.
    same = ModelClassifier().train(without[:150], without[150:300])
    assert same.accuracy(with_gaze[300:] - 1.0, without[300:]) < 0.62


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-10, 10), min_size=3, max_size=40, unique=True),
       st.floats(0.1, 5))
@example([0.0, 6.263147759365113e-190, 9.17072640017171e-240], 1.0)  # once 0/0 in corrcoef
def test_recovery_of_exact_estimates(values, width):
    """Estimates equal to the truth: r = 1, no bias, full coverage; shifted out: none."""
    true = np.array(values)
    r = recovery("x", true, true, true - width, true + width)
    assert r.correlation == pytest.approx(1.0) and r.bias == 0.0 and r.coverage == 1.0
    assert not r.identifiable  # coverage 1.0 is above 0.98: intervals too wide to trust
    off = recovery("x", true, true + 3 * width, true + 2 * width, true + 4 * width)
    assert off.coverage == 0.0 and off.bias == pytest.approx(3 * width)


def test_identifiable_needs_both_correlation_and_coverage():
    true = np.linspace(0, 1, 100)
    inside = np.where(np.arange(100) % 10 == 0, 5.0, true)  # 90 % of intervals hold the truth
    good = recovery("x", true, true, inside - 0.01, inside + 0.01)
    assert good.coverage == pytest.approx(0.9) and good.identifiable
    flat = recovery("x", true, np.full(100, 0.5), true - 0.01, true + 0.01)
    assert math.isnan(flat.correlation) and not flat.identifiable
    assert flat.as_dict()["correlation"] is None  # JSON has no NaN


def test_coverage_below_the_standard_fails_however_good_the_correlation():
    # Intervals that miss the truth too often (overconfident) are not findings: r = 1 and no
    # bias do not rescue a coverage below 0.80, nor do single-value intervals.
    true = np.linspace(0, 1, 100)
    for k, identifiable in ((0, False), (50, False), (79, False), (80, True), (90, True)):
        hit = np.arange(100) < k  # k of 100 intervals hold the truth
        centre = np.where(hit, true, true + 0.5)
        r = recovery("x", true, true, centre - 0.01, centre + 0.01)
        assert r.correlation == pytest.approx(1.0) and r.bias == 0.0
        assert r.coverage == pytest.approx(k / 100) and r.identifiable == identifiable, k
    exact_but_wrong = recovery("flag", true, true, true + 1.0, true + 1.0)
    assert exact_but_wrong.exact == 1.0 and exact_but_wrong.coverage == 0.0
    assert not exact_but_wrong.identifiable


@given(st.floats(0.0, 1.0), st.floats(0.7, 1.0), st.sampled_from([0.0, 0.49, 0.5, 1.0]))
@example(0.8, 0.7, 0.0)
@example(0.7999, 1.0, 1.0)
@example(0.98, 0.7, 0.0)
@example(0.9801, 1.0, 0.49)
def test_identifiable_is_the_standard(coverage, r, exact):
    # The standard (module docstring, `nod fit` report): r ≥ 0.7 and coverage of the 90 %
    # intervals within 0.80-0.98; above 0.98 only when most intervals are one value.
    rec = Recovery("x", r, 0.0, coverage, 100, exact)
    within = coverage >= 0.80 and (coverage <= 0.98 or exact >= 0.5)
    assert rec.identifiable == within
    assert not Recovery("x", 0.69, 0.0, coverage, 100, exact).identifiable


def test_a_0_1_parameter_named_exactly_is_identifiable_despite_full_coverage():
    true = np.array([0.0, 1.0] * 50)
    sharp = recovery("flag", true, true, true, true)  # every set is the one true value
    assert sharp.coverage == 1.0 and sharp.exact == 1.0 and sharp.identifiable
    vague = recovery("flag", true, true, np.zeros(100), np.ones(100))  # always "0 or 1"
    assert vague.coverage == 1.0 and vague.exact == 0.0 and not vague.identifiable


def test_a_0_1_parameter_gets_a_probability_and_a_set():
    rng = np.random.default_rng(4)
    flag = (rng.random(800) < 0.4).astype(float)
    summaries = np.column_stack([flag + rng.normal(0, 0.2, 800), rng.normal(0, 1, 800)])
    theta = np.column_stack([flag, rng.uniform(0, 1, 800)])
    est = QuantileEstimator(("flag", "other"), seed=1).train(theta, summaries)
    check = est.check[0]
    assert check.identifiable and check.correlation > 0.9 and check.exact > 0.8
    fit = est.predict(summaries[:50])
    prob = fit.probability[:, 0]
    assert np.all((prob >= 0) & (prob <= 1))  # its probability, beside the estimate
    assert np.array_equal(fit.estimate[:, 0], (prob >= 0.5).astype(float))  # the likelier value
    assert set(np.unique(fit.low[:, 0])) <= {0.0, 1.0} and np.all(fit.low <= fit.high)
    assert np.isnan(fit.probability[:, 1]).all()  # a continuous parameter has none
    assert np.array_equal(fit.graded[:, 0], prob) and np.array_equal(fit.graded[:, 1],
                                                                       fit.estimate[:, 1])


def _inside(fit: Estimates) -> None:
    """Every estimate inside its own interval or set; a 0/1 one a value of its set."""
    assert np.all(fit.low <= fit.estimate) and np.all(fit.estimate <= fit.high)
    kinds = np.isfinite(fit.probability)
    assert set(np.unique(fit.estimate[kinds])) <= {0.0, 1.0}
    assert set(np.unique(fit.low[kinds])) | set(np.unique(fit.high[kinds])) <= {0.0, 1.0}
    for i, p in zip(*np.nonzero(kinds), strict=True):
        cell = parameter_cell(fit.estimate[i, p], fit.low[i, p], fit.high[i, p],
                              fit.probability[i, p])
        assert cell["estimate"] in cell["set"] and 0 <= cell["probability"] <= 1
        assert cell["low"] == min(cell["set"]) and cell["high"] == max(cell["set"])


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(40, 160), share=st.floats(0.0, 1.0),
       signal=st.floats(0.0, 3.0), shift=st.floats(-2.0, 0.5))
def test_every_estimate_lies_inside_its_own_interval_or_set(seed, n, share, signal, shift):
    """Over random tables and people: a continuous, a log-normal and a 0/1 parameter, their
    summaries anything from informative to noise; and with the conformal margins pushed below
    0 (`shift`), where the interval would narrow past the median if nothing took it in again."""
    rng = np.random.default_rng(seed)
    theta = np.column_stack([rng.normal(0, 1, n), np.exp(rng.normal(1, 1.2, n)),
                             (rng.random(n) < share).astype(float)])
    summaries = np.column_stack([signal * theta[:, 0] + rng.normal(0, 1, n),
                                 signal * np.log(theta[:, 1]) + rng.normal(0, 1, n),
                                 signal * theta[:, 2] + rng.normal(0, 1, n)])
    summaries[rng.random(summaries.shape) < 0.1] = np.nan
    est = QuantileEstimator(("linear", "gain", "kind"), seed=seed % 1000).train(theta, summaries)
    people = rng.normal(0, 2, (30, 3))
    _inside(est.predict(people))
    est._margin = est._margin + shift * np.array([1.0, 1.0, 0.0])  # a 0/1 set has no margin
    _inside(est.predict(people))


def test_the_recovery_table_keeps_its_columns_for_a_long_name():
    from services.fit.report import recovery_table

    true = np.linspace(0, 1, 20)
    checks = [recovery(n, true, true, true - 0.1, true + 0.1)
              for n in ("speed", "persistent_contrarian")]
    spread = [recovery_intervals(c, true, true, true - 0.1, true + 0.1, seed=1) for c in checks]
    for table in (recovery_table(checks, None), recovery_table(checks, None, spread)):
        rows = table.splitlines()[:3]
        verdict = r" (yes|NO)( \(at the edge\))?$"
        ends = {rows[0].index("identifiable")} | {re.search(verdict, r).start(1) for r in rows[1:]}
        assert len(ends) == 1, rows  # "identifiable" and each row's yes/NO start in one column
        assert rows[2].startswith("persistent_contrarian ")
    assert "[1.00, 1.00]" in table and "[0.84, 1.00]" in table  # r; Wilson of 20 of 20


def test_a_log_normal_parameter_is_correlated_on_its_log():
    rng = np.random.default_rng(7)
    true = np.exp(rng.normal(2.0, 1.1, 60))  # gaze_gain-like: a decade and more across people
    estimate = true * np.exp(rng.normal(0.0, 0.6, 60))
    estimate[np.argmax(true)] = np.median(true)  # the top person read as typical
    raw = recovery("g", true, estimate, estimate / 3, estimate * 3)
    logged = recovery("g", true, estimate, estimate / 3, estimate * 3, log=True)
    assert logged.scale == "log" and raw.scale == "linear"
    assert logged.correlation == pytest.approx(np.corrcoef(np.log(true), np.log(estimate))[0, 1])
    assert logged.correlation > 0.7 > raw.correlation  # one person sets the raw r
    assert (logged.coverage, logged.bias) == (raw.coverage, raw.bias)  # units unchanged
    zero = recovery("z", true - true.min(), estimate, estimate, estimate, log=True)
    assert zero.scale == "linear"  # a value of 0 has no log: r of the values as they are


def test_the_bootstrap_interval_of_r_holds_r_narrows_with_people_and_repeats():
    rng = np.random.default_rng(5)
    true = rng.normal(0, 1, 1000)
    estimate = true + rng.normal(0, 1, 1000)  # r ≈ 0.71: at the standard's edge
    widths = []
    for n in (40, 400):
        r = correlation(true[:n], estimate[:n])
        lo, hi = bootstrap_correlation(true[:n], estimate[:n], seed=3)
        assert lo < r < hi
        assert bootstrap_correlation(true[:n], estimate[:n], seed=3) == (lo, hi)  # a rerun
        widths.append(hi - lo)
    assert widths[1] < widths[0] / 2  # ten times the people: about a third as wide
    assert math.isnan(bootstrap_correlation(np.ones(5), np.arange(5.0), seed=1)[0])


@pytest.mark.parametrize(("k", "n"), [(0, 10), (54, 60), (60, 60), (27, 30), (1, 1)])
def test_wilson_is_scipys_wilson(k, n):
    from scipy.stats import binomtest

    expected = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    assert wilson(k, n) == pytest.approx((expected.low, expected.high), abs=1e-9)


def test_wilson_of_a_known_case():
    # 54 of 60 (coverage 0.90): 0.7985-0.9534 (Wilson 1927's score interval, z = 1.95996).
    lo, hi = wilson(54, 60)
    assert lo == pytest.approx(0.79846, abs=1e-4) and hi == pytest.approx(0.95336, abs=1e-4)


def test_a_verdict_whose_intervals_reach_across_a_threshold_is_at_the_edge():
    rng = np.random.default_rng(6)
    true = rng.normal(0, 1, 400)
    sharp = true + rng.normal(0, 0.1, 400)  # r ≈ 0.99, far from 0.7
    band = (sharp - 0.165, sharp + 0.165)  # a 90 % interval
    firm = recovery("a", true, sharp, *band)
    u = recovery_intervals(firm, true, sharp, *band, seed=1)
    assert firm.identifiable and 0.85 < firm.coverage < 0.95 and not u["edge"]
    # The same on 60 people: a coverage near 0.90 cannot rule out 0.80 (Wilson ±0.08).
    few = recovery("a", true[:60], sharp[:60], band[0][:60], band[1][:60])
    w = recovery_intervals(few, true[:60], sharp[:60], band[0][:60], band[1][:60], seed=1)
    assert w["coverage_ci95"][0] < 0.80 and w["edge"]
    near = true[:60] + rng.normal(0, 1.0, 60)  # r ≈ 0.7
    wide = np.full(60, 10.0)
    loose = recovery("b", true[:60], near, near - wide, near + wide)
    v = recovery_intervals(loose, true[:60], near, near - wide, near + wide, seed=1)
    assert v["correlation_ci95"][0] < 0.7 < v["correlation_ci95"][1] and v["edge"]


def test_the_sets_of_a_kind_are_conformal_they_hold_the_truth_for_90_percent():
    """A 0/1 parameter the summaries show only in part: its sets, calibrated on the table, hold
    the truth for about 90 % of fresh people of the prior (not the ≥ 97 % of every value at
    least 10 % likely), each holds its most likely value, and sure people get one value."""
    def people(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng(seed)
        kind = (rng.random(n) < 0.4).astype(float)
        summaries = np.column_stack([kind * 1.2 + rng.normal(0, 1, n), rng.normal(0, 1, n)])
        return kind[:, None], summaries

    est = QuantileEstimator(("kind",), seed=0).train(*people(3000, 1))
    truth, summaries = people(4000, 2)
    fit = est.predict(summaries)
    inside = (fit.low[:, 0] <= truth[:, 0]) & (truth[:, 0] <= fit.high[:, 0])
    assert 0.87 <= inside.mean() <= 0.94
    assert np.all((fit.low <= fit.estimate) & (fit.estimate <= fit.high))
    single = fit.low[:, 0] == fit.high[:, 0]
    assert 0.05 < single.mean() < 0.95  # some sets name a value, the unsure ones both
    sure = np.abs(fit.probability[:, 0] - 0.5) > 0.45
    assert single[sure].all()
