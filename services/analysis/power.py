"""Power analysis: how likely a study of N participants detects the effects of Sec 7.

Method (studies drawn from several independent simulated populations): K populations of
simulated participants (`populations`; population j has the seeds seed + j·size …, so no person
is in two) are run once, offline, on the compute engine, as `nod cohort` runs a cohort (the
default simulated person is the one fitted to the paper, `services.cohort.person`; `--params`
for another). From each population, `runs` studies of N participants are drawn *without*
replacement: N distinct people of a population of independently simulated people are N fresh
people of the model, so every drawn study is, on its own, a study of fresh people. Each is
analysed exactly as a real one (phase categories, paired tables, Stuart–Maxwell) and its
p-values are adjusted over its defined tests as `nod analyze study` adjusts them (Holm by
default) and, beside that, left unadjusted (the paper's uncorrected tests).

The studies of one population share its people, so they are not independent: one population of
400 gave the 4→5 test a power of 0.43 at N = 51 where fresh populations gave 0.16–0.23. The
power is therefore pooled over populations (the share of significant studies over all of them,
which equals the mean of the populations' shares) and its 95 % interval is taken over the
populations, the independent units: mean ± t(0.975, K − 1)·s/√K, s the standard deviation of
the K per-population shares, so both the Monte-Carlo error of the draws and the spread between
populations are in it (`pooled_interval`). Why not a two-level bootstrap (populations
resampled, then studies): with the few populations a 2-core machine affords (6 by default) its
percentile interval is too narrow — it cannot reach past the most extreme population and
underestimates the variance by (K − 1)/K — while the t interval is built for a few independent
units. When every population gives the same share (all 1.00, say) s is 0; the interval is then
widened to at least the Wilson interval of all draws, the Monte-Carlo error alone.

`implied_power` is the power the paper's own statistics imply (`PAPER_TESTS`): under the
alternative the Stuart–Maxwell X² is approximately noncentral χ²(df, λ) with E X² = df + λ, so
λ̂ = X² − df (at least 0) is the moment estimate of the noncentrality from one published study;
λ = X² itself (the plug-in "observed power") is reported beside it as the optimistic reading.
λ grows in proportion to N, so at another N it is λ̂·N/51.
The simulated power is that of the *model's* effect, which is as good as its calibration.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import stats

from services.analysis.multiplicity import NAMES, Correction, adjust
from services.analysis.paper_claims import PAPER_STATISTIC
from services.analysis.stuart_maxwell import stuart_maxwell
from services.analysis.study import (
    ADJACENT_PAIRS,
    CONTROL_TRIALS,
    EXPERIMENT_TRIALS,
    paired_table,
    phase_category,
)
from services.cohort.outcomes import Outcomes, session_outcomes
from services.compute.engine import Engine
from services.model.params import NodConfig

if TYPE_CHECKING:
    from matplotlib.figure import Figure

TESTS = ("control_vs_experiment", *(f"trial_{a}_vs_{b}" for a, b in ADJACENT_PAIRS))

PAPER_N = 51  # the paper's participants
# The paper's Stuart–Maxwell statistics and their df (Secs 7.1-7.2). The df are those its
# p-values are the χ² tails of (docs/study.md, "Paper check"): 4→5 has all four categories
# (df 3), the others three (df 2). Control vs experiment: 68.125 as published, although the
# published table gives 27.0 (paper_claims) — the power is of the effect the paper reported.
PAPER_TESTS: dict[str, tuple[float, int]] = {
    "control_vs_experiment": (PAPER_STATISTIC, 2),
    "trial_4_vs_5": (12.39, 3),
    "trial_5_vs_6": (9.48, 2),
    "trial_6_vs_7": (2.57, 2),
    "trial_7_vs_8": (0.44, 2),
}


def populations(
    engine: Engine, cfg: NodConfig, k: int, size: int, seed: int,
    progress: Callable[[], None] | None = None,
) -> list[list[Outcomes]]:
    """`k` independent populations of `size` simulated participants' outcomes (trials 1..8).

    Population j is the people of seeds seed + j·size … seed + (j+1)·size − 1: disjoint seed
    ranges, so the populations share nobody. All k·size sessions go to the engine in one map,
    which keeps every worker busy to the end.
    """
    jobs = [(cfg, seed + i) for i in range(k * size)]
    flat: list[Outcomes] = []
    for outcomes in engine.imap(session_outcomes, jobs):
        flat.append(outcomes)
        if progress:
            progress()
    return [flat[j * size:(j + 1) * size] for j in range(k)]


def p_values(study: Sequence[Sequence[str | None]]) -> dict[str, float]:
    """Every test of the study analysis on one study's outcomes (nan where undefined)."""

    def p_of(table: np.ndarray) -> float:
        try:
            return stuart_maxwell(table).p
        except ValueError:  # one category, or all pairs concordant: nothing to test
            return math.nan

    phases = [
        (
            phase_category([o[t - 1] for t in CONTROL_TRIALS]),
            phase_category([o[t - 1] for t in EXPERIMENT_TRIALS]),
        )
        for o in study
    ]
    out = {"control_vs_experiment": p_of(paired_table(phases))}
    for a, b in ADJACENT_PAIRS:
        out[f"trial_{a}_vs_{b}"] = p_of(paired_table((o[a - 1], o[b - 1]) for o in study))
    return out


def significant(
    raw: dict[str, float], alpha: float, correction: Correction
) -> dict[str, bool]:
    """Which tests of one study are significant: p adjusted over its defined tests < α.

    An untestable (nan) test is never significant and does not count in the adjustment.
    """
    defined = {t: p for t, p in raw.items() if not math.isnan(p)}
    adjusted = dict(zip(defined, adjust(list(defined.values()), correction), strict=True))
    return {t: t in adjusted and bool(adjusted[t] < alpha) for t in raw}


def wilson(hits: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a proportion."""
    if n == 0:
        return (0.0, 1.0)
    p = hits / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    lo, hi = max(0.0, centre - half), min(1.0, centre + half)
    return (min(lo, p), max(hi, p))  # rounding must not leave p outside its own interval


def pooled_interval(hits: Sequence[int], runs: int, level: float = 0.95) -> tuple[float, float]:
    """95 % interval of the pooled power from each population's significant studies of `runs`.

    The populations are the independent units: mean ± t(K − 1)·s/√K over their shares (the
    between-population spread and the Monte-Carlo error both), never narrower than the Wilson
    interval of all K·runs draws (the Monte-Carlo error alone; the t interval is narrower only
    when the shares hardly differ, e.g. all 1.00). One population: the Wilson interval only.
    """
    k = len(hits)
    if k == 0 or runs <= 0:
        raise ValueError("pooled_interval needs at least one population of at least one study")
    mc = wilson(sum(hits), k * runs)
    if k == 1:
        return mc
    shares = [h / runs for h in hits]
    mean = statistics.fmean(shares)
    half = float(stats.t.ppf(0.5 + level / 2, k - 1)) * statistics.stdev(shares) / math.sqrt(k)
    return (max(0.0, min(mean - half, mc[0])), min(1.0, max(mean + half, mc[1])))


def power(
    pops: Sequence[Sequence[Sequence[str | None]]],
    sizes: Sequence[int],
    runs: int,
    alpha: float = 0.05,
    seed: int = 0,
    corrections: Sequence[Correction] = ("holm", "none"),
) -> list[dict[str, Any]]:
    """Per study size: each test's pooled power under each correction, with its interval.

    `runs` studies of N distinct people are drawn from each population (N ≤ its size). Per
    correction: `power` (pooled share of significant draws), `ci95` (`pooled_interval`),
    `by_population` (each population's share: the spread one population would hide) and
    `monte_carlo_ci95` (the Wilson interval of all draws, as if they were independent).
    """
    if not pops:
        raise ValueError("power needs at least one population")
    small = min(len(p) for p in pops)
    if max(sizes) > small:
        raise ValueError(
            f"a study of {max(sizes)} distinct people cannot be drawn from a population of {small}"
        )
    rng = np.random.default_rng(seed)
    result = []
    for n in sizes:
        hits = {c: {t: [0] * len(pops) for t in TESTS} for c in corrections}
        for j, pop in enumerate(pops):
            for _ in range(runs):
                study = [pop[i] for i in rng.choice(len(pop), size=n, replace=False)]
                raw = p_values(study)
                for c in corrections:
                    for test, yes in significant(raw, alpha, c).items():
                        hits[c][test][j] += yes
        k = len(pops)
        result.append({
            "participants": n,
            "runs": runs,
            "populations": k,
            "power": {c: {t: sum(hits[c][t]) / (k * runs) for t in TESTS} for c in corrections},
            "ci95": {c: {t: list(pooled_interval(hits[c][t], runs)) for t in TESTS}
                     for c in corrections},
            "by_population": {c: {t: [h / runs for h in hits[c][t]] for t in TESTS}
                              for c in corrections},
            "monte_carlo_ci95": {c: {t: list(wilson(sum(hits[c][t]), k * runs)) for t in TESTS}
                                 for c in corrections},
        })
    return result


def ncx2_power(df: int, noncentrality: float, alpha: float = 0.05) -> float:
    """Power of a χ²(df) test at level α when the statistic is noncentral χ²(df, λ)."""
    if df < 1 or noncentrality < 0 or not 0 < alpha < 1:
        raise ValueError(f"need df >= 1, λ >= 0, 0 < α < 1; got {df}, {noncentrality}, {alpha}")
    critical = float(stats.chi2.isf(alpha, df))
    if noncentrality == 0:
        return float(stats.chi2.sf(critical, df))  # = α: the null
    return float(stats.ncx2.sf(critical, df, noncentrality))


def implied_power(
    statistic: float, df: int, n: int = PAPER_N, alpha: float = 0.05, of_n: int = PAPER_N
) -> dict[str, float]:
    """The power at N = n that one published Stuart–Maxwell X² (df, from `of_n` people) implies.

    `noncentrality` is the moment estimate max(X² − df, 0)·n/of_n (E X² = df + λ, λ ∝ N) and
    `power` its power; `power_plug_in` takes λ = X²·n/of_n, the "observed power", which is
    biased up (it counts the null's own df as effect).
    """
    lam = max(statistic - df, 0.0) * n / of_n
    return {
        "statistic": statistic,
        "df": df,
        "participants": n,
        "noncentrality": lam,
        "power": ncx2_power(df, lam, alpha),
        "power_plug_in": ncx2_power(df, statistic * n / of_n, alpha),
    }


def paper_implied(sizes: Sequence[int], alpha: float = 0.05) -> dict[str, Any]:
    """`implied_power` of every paper test at N = 51 and at each of `sizes` (uncorrected α)."""
    ns = sorted({PAPER_N, *sizes})
    return {
        "alpha": alpha,
        "correction": "none",
        "noncentrality": "max(X² − df, 0)·N/51 (moment estimate); power_plug_in: X²·N/51",
        "tests": {t: {str(n): implied_power(x, df, n, alpha) for n in ns}
                  for t, (x, df) in PAPER_TESTS.items()},
    }



def draw(doc: dict[str, Any]) -> Figure:
    """Power against N for every test, one panel per correction (Holm, then uncorrected).

    Intervals are the population-inclusive ones; in the uncorrected panel a cross at each N
    marks the power the paper's own statistic implies (noncentral χ², `implied_power`), so the
    model's power and the paper's stand side by side. The legend sits outside the axes, so it
    never hides a point (power is anywhere in [0, 1]); the tests' points at one N are drawn
    slightly apart (1 % of the N range) so none hides another's interval.
    """
    from services.analysis.figures import pyplot

    plt = pyplot()
    corrections = list(doc["results"][0]["power"])
    fig, axes = plt.subplots(1, len(corrections), figsize=(4.2 * len(corrections) + 1, 4.8),
                             layout="constrained", sharey=True, squeeze=False)
    sizes = [r["participants"] for r in doc["results"]]
    step = 0.01 * ((max(sizes) - min(sizes)) or max(sizes))  # side by side at each N
    implied = doc.get("paper_implied", {}).get("tests", {})
    for ax, corr in zip(axes[0], corrections, strict=True):
        for k, test in enumerate(TESTS):
            y = [r["power"][corr][test] for r in doc["results"]]
            lo = [r["power"][corr][test] - r["ci95"][corr][test][0] for r in doc["results"]]
            hi = [r["ci95"][corr][test][1] - r["power"][corr][test] for r in doc["results"]]
            x = [n + (k - (len(TESTS) - 1) / 2) * step for n in sizes]
            line = ax.errorbar(x, y, yerr=[lo, hi], marker="o", capsize=3,
                               label=test.replace("_", " ") if ax is axes[0][0] else None)
            if corr == "none" and test in implied:
                ns = sorted(int(n) for n in implied[test])
                ax.plot(ns, [implied[test][str(n)]["power"] for n in ns], ls="none", marker="x",
                        ms=7, color=line.lines[0].get_color())
        ax.axhline(0.8, color="grey", lw=0.8, ls="--")
        ax.set_xlabel("participants")
        ax.set_ylim(-0.02, 1.02)
        ax.set_title(f"{NAMES[corr]}, α = {doc['alpha']}", fontsize=10)
    axes[0][0].set_ylabel("power (simulated cohort, a model)")
    if implied:
        axes[0][0].plot([], [], ls="none", marker="x", color="black",
                        label="paper's X² implies (noncentral χ²)")
    fig.legend(fontsize=7, loc="outside lower center", ncol=3, frameon=False)
    return fig


def plot(doc: dict[str, Any], path: str) -> None:
    """Draw the power figure (`draw`) into a file; the suffix picks the format."""
    from services.analysis.figures import pyplot

    fig = draw(doc)
    try:
        fig.savefig(path, dpi=150)
    finally:
        pyplot().close(fig)
