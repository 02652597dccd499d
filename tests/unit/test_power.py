"""Power with its population uncertainty (services.analysis.power; issue 35, item 5).

Studies are drawn from several independent populations; the pooled power's interval must hold
the spread between populations, not only the Monte-Carlo error; Holm and the uncorrected α sit
side by side; the paper's own statistics give a noncentral-χ² power, checked against scipy, an
independent series and a simulation of the Stuart–Maxwell statistic itself.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from services.analysis.cli import main as analyze
from services.analysis.power import (
    PAPER_TESTS,
    TESTS,
    implied_power,
    ncx2_power,
    paper_implied,
    pooled_interval,
    populations,
    power,
    wilson,
)
from services.analysis.stuart_maxwell import stuart_maxwell
from services.cohort.outcomes import session_outcomes
from services.cohort.person import load_cohort_params

SHIFT = ["D", "D", "D", "C", "C", "C", "C", "C"]  # control D, experiment C: a large shift
STAY = ["D"] * 8


class SerialEngine:
    """The engine's imap, in this process (the populations' seeds are what is tested)."""

    def imap(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        return map(fn, items)


def test_populations_are_disjoint_seed_ranges_of_the_cohort_engine() -> None:
    cfg = load_cohort_params(None)
    pops = populations(SerialEngine(), cfg, k=2, size=2, seed=5)  # type: ignore[arg-type]
    assert [len(p) for p in pops] == [2, 2]
    # population j holds seeds 5 + 2j, 6 + 2j: nobody is in two populations
    assert pops[1][0] == session_outcomes((cfg, 7)) and pops[0][1] == session_outcomes((cfg, 6))


def test_a_study_is_distinct_people_of_its_population() -> None:
    # A population of exactly N people: every draw without replacement is the whole population,
    # so each population's share is exactly 0 or 1 (drawn with replacement it would vary).
    pop = [SHIFT] * 12 + [STAY] * 8
    doc = power([pop], [20], runs=15, seed=3)[0]
    share = doc["by_population"]["holm"]["control_vs_experiment"]
    assert share in ([0.0], [1.0])
    with pytest.raises(ValueError, match="distinct people"):
        power([pop], [21], runs=1)


def test_two_unlike_populations_widen_the_interval_past_the_monte_carlo_error() -> None:
    strong = [SHIFT] * 60 + [STAY] * 40
    none = [STAY] * 100
    r = power([strong, none, strong, none], [30], runs=40, seed=1)[0]
    for corr in ("holm", "none"):
        by = r["by_population"][corr]["control_vs_experiment"]
        assert by[1] == by[3] == 0.0 and min(by[0], by[2]) > 0.9
        pooled = r["power"][corr]["control_vs_experiment"]
        assert pooled == pytest.approx(sum(by) / 4)
        lo, hi = r["ci95"][corr]["control_vs_experiment"]
        mc_lo, mc_hi = r["monte_carlo_ci95"][corr]["control_vs_experiment"]
        assert lo <= mc_lo <= pooled <= mc_hi <= hi
        assert hi - lo > 3 * (mc_hi - mc_lo)  # the populations' spread dominates
    assert set(r["power"]) == {"holm", "none"} and set(r["power"]["none"]) == set(TESTS)


def test_uncorrected_power_is_never_below_holm_on_model_draws() -> None:
    cfg = load_cohort_params(None)
    pops = populations(SerialEngine(), cfg, k=2, size=24, seed=11)  # type: ignore[arg-type]
    for r in power(pops, [12, 24], runs=20, seed=4):
        for t in TESTS:
            holm, none = r["by_population"]["holm"][t], r["by_population"]["none"][t]
            assert all(a <= b for a, b in zip(holm, none, strict=True)), (t, holm, none)


def test_pooled_interval_worked_example() -> None:
    # Shares 0.1 … 0.5 of 100 studies: mean 0.3, sd 0.158, t(0.975, 4) = 2.776 → ± 0.196.
    lo, hi = pooled_interval([10, 20, 30, 40, 50], 100)
    half = stats.t.ppf(0.975, 4) * np.std([0.1, 0.2, 0.3, 0.4, 0.5], ddof=1) / math.sqrt(5)
    assert (lo, hi) == pytest.approx((0.3 - half, 0.3 + half))
    assert half == pytest.approx(0.196, abs=1e-3)
    # No spread at all: the Monte-Carlo error of all the draws is what is left.
    assert pooled_interval([100] * 6, 100) == wilson(600, 600)
    assert pooled_interval([7], 20) == wilson(7, 20)
    with pytest.raises(ValueError):
        pooled_interval([], 10)


@given(
    st.integers(min_value=1, max_value=60).flatmap(
        lambda runs: st.tuples(
            st.just(runs), st.lists(st.integers(0, runs), min_size=2, max_size=12)
        )
    )
)
def test_pooled_interval_holds_the_mean_and_the_monte_carlo_error(
    case: tuple[int, list[int]],
) -> None:
    runs, hits = case
    lo, hi = pooled_interval(hits, runs)
    mean = sum(hits) / (len(hits) * runs)
    mc = wilson(sum(hits), len(hits) * runs)
    assert 0.0 <= lo <= mean <= hi <= 1.0
    assert lo <= mc[0] + 1e-12 and hi >= mc[1] - 1e-12


def test_pooled_interval_covers_the_true_power_when_populations_differ() -> None:
    # Populations whose own power scatters (sd 0.08) around 0.3, 6 of them, 100 studies each:
    # the population-inclusive interval covers 0.3 about 95 % of the time; the Wilson interval
    # of the pooled draws (the old report's kind) far less often.
    rng = np.random.default_rng(7)
    reps, k, runs, truth = 2000, 6, 100, 0.3
    ours = mc = 0
    for _ in range(reps):
        p = np.clip(rng.normal(truth, 0.08, k), 0, 1)
        hits = [int(h) for h in rng.binomial(runs, p)]
        lo, hi = pooled_interval(hits, runs)
        ours += lo <= truth <= hi
        wlo, whi = wilson(sum(hits), k * runs)
        mc += wlo <= truth <= whi
    assert 0.92 <= ours / reps <= 0.98
    assert mc / reps < 0.80


def test_ncx2_power_at_the_null_is_alpha_and_matches_scipy() -> None:
    for df in (1, 2, 3, 5):
        assert ncx2_power(df, 0.0, 0.05) == pytest.approx(0.05, abs=1e-12)
    # 4→5: X² 12.39, df 3 → λ̂ = 9.39 at N = 51; the critical value χ²(3) 0.95 is 7.815.
    got = implied_power(12.39, 3)
    assert got["noncentrality"] == pytest.approx(9.39)
    assert got["power"] == pytest.approx(stats.ncx2.sf(7.814727903, 3, 9.39), rel=1e-7)
    assert got["power_plug_in"] == pytest.approx(stats.ncx2.sf(7.814727903, 3, 12.39), rel=1e-7)
    assert 0.70 < got["power"] < 0.76  # the paper's own 4→5 result was far from certain
    # λ grows with N: at 102 people the noncentrality doubles.
    assert implied_power(12.39, 3, n=102)["noncentrality"] == pytest.approx(18.78)
    # 7→8 is below its df: λ̂ = 0, the power is α.
    assert implied_power(0.44, 2)["power"] == pytest.approx(0.05)
    with pytest.raises(ValueError):
        ncx2_power(0, 1.0)


def _series(df: int, lam: float, alpha: float) -> float:
    """P(χ'²(df, λ) > c) as a Poisson mixture of central χ² tails: independent of ncx2."""
    c = stats.chi2.isf(alpha, df)
    j = np.arange(0, 400)
    return float(np.sum(stats.poisson.pmf(j, lam / 2) * stats.chi2.sf(c, df + 2 * j)))


@settings(max_examples=60, deadline=None)
@given(
    st.integers(min_value=1, max_value=6),
    st.floats(min_value=0.0, max_value=60.0),
    st.floats(min_value=0.001, max_value=0.2),
)
def test_ncx2_power_is_the_poisson_mixture_and_grows_with_lambda(
    df: int, lam: float, alpha: float
) -> None:
    got = ncx2_power(df, lam, alpha)
    assert got == pytest.approx(_series(df, lam, alpha), abs=1e-7)
    assert alpha - 1e-9 <= got <= 1.0
    assert ncx2_power(df, lam + 1.0, alpha) >= got - 1e-12


def test_ncx2_power_agrees_with_simulated_stuart_maxwell_tables() -> None:
    # Paired 3-category tables with a small marginal shift, N = 120: the Stuart–Maxwell X² is
    # close to noncentral χ²(2, λ), λ = N·δᵀS⁻¹δ (δ the marginal difference, S its per-person
    # matrix), so its mean is df + λ (why λ̂ = X² − df) and its power is ncx2_power's.
    pi = np.array([[0.30, 0.06, 0.02], [0.10, 0.20, 0.03], [0.05, 0.04, 0.20]])
    n, reps, df = 120, 3000, 2
    rows, cols = pi.sum(axis=1), pi.sum(axis=0)
    delta = (rows - cols)[:2]
    s = -(pi + pi.T)
    np.fill_diagonal(s, rows + cols - 2 * np.diag(pi))
    lam = n * float(delta @ np.linalg.solve(s[:2, :2], delta))
    rng = np.random.default_rng(3)
    xs = []
    for _ in range(reps):
        table = rng.multinomial(n, pi.ravel()).reshape(3, 3)
        xs.append(stuart_maxwell(table).statistic)
    x = np.array(xs)
    predicted = ncx2_power(df, lam)
    se = math.sqrt(predicted * (1 - predicted) / reps)
    assert 0.3 < predicted < 0.8  # a shift the test finds only sometimes
    assert abs(float(np.mean(x > stats.chi2.isf(0.05, df))) - predicted) < 4 * se + 0.02
    assert float(np.mean(x)) - df == pytest.approx(lam, rel=0.12)


def test_paper_implied_covers_every_test_at_51_and_the_sizes() -> None:
    doc = paper_implied([20, 60])
    assert set(doc["tests"]) == set(TESTS) == set(PAPER_TESTS)
    for t, (x, df) in PAPER_TESTS.items():
        row = doc["tests"][t]
        assert sorted(row, key=int) == ["20", "51", "60"]
        assert row["51"]["statistic"] == x and row["51"]["df"] == df
        assert row["20"]["power"] <= row["51"]["power"] <= row["60"]["power"]
        assert row["51"]["power"] <= row["51"]["power_plug_in"]


def test_nod_analyze_power_json_carries_both_alphas_with_population_intervals(
    capsys: pytest.CaptureFixture[str],
) -> None:
    argv = ["power", "--participants", "4,6", "--runs", "5", "--populations", "2",
            "--population", "10", "--workers", "1", "--json"]
    assert analyze(argv) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["populations"] == 2 and doc["population"] == 10 and doc["seeds"] == [1, 20]
    assert doc["corrections"] == ["holm", "none"]
    for r in doc["results"]:
        assert r["populations"] == 2
        for corr in ("holm", "none"):
            for t in TESTS:
                lo, hi = r["ci95"][corr][t]
                assert lo <= r["power"][corr][t] <= hi
                assert len(r["by_population"][corr][t]) == 2
    assert doc["paper_implied"]["tests"]["trial_4_vs_5"]["51"]["df"] == 3
    # A study larger than a population cannot be drawn from distinct people: refused.
    assert analyze(["power", "--participants", "11", "--population", "10", "--workers", "1"]) == 2
    assert "--population" in capsys.readouterr().err
