"""Power analysis: how likely a study of N participants detects the effects of Sec 7.

Method (resampling from one simulated population): a population of simulated participants is
run once, offline, on the compute engine (the default simulated person is the one fitted to the
paper, `services.cohort.person`; `--params` for another); a study of N participants is then drawn
from it with replacement, `runs` times, and each drawn study is analysed exactly as a real one
(phase categories, paired tables, Stuart–Maxwell, the p-values adjusted over the family of
defined tests as `nod analyze study` adjusts them: Holm by default). The power of a test at N
is the share of drawn studies in which its adjusted p is below α; its Monte-Carlo error is the
Wilson 95% interval.
Resampling keeps the cost at one population, however many N and runs; the population must be
large against N (default 400 for N up to 60), or the draws repeat the same people too often.
The power is that of the *model's* effect, which is as good as its calibration.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from services.analysis.multiplicity import Correction, adjust
from services.analysis.stuart_maxwell import stuart_maxwell
from services.analysis.study import (
    ADJACENT_PAIRS,
    CONTROL_TRIALS,
    EXPERIMENT_TRIALS,
    paired_table,
    phase_category,
)
from services.cohort.outcomes import session_outcomes
from services.compute.engine import Engine
from services.model.params import NodConfig

if TYPE_CHECKING:
    from matplotlib.figure import Figure

TESTS = ("control_vs_experiment", *(f"trial_{a}_vs_{b}" for a, b in ADJACENT_PAIRS))


def population(
    engine: Engine, cfg: NodConfig, size: int, seed: int,
    progress: Callable[[], None] | None = None,
) -> list[list[str | None]]:
    """`size` simulated participants' outcomes (trials 1..8), seeds seed..seed+size-1."""
    out: list[list[str | None]] = []
    for outcomes in engine.imap(session_outcomes, [(cfg, seed + i) for i in range(size)]):
        out.append(outcomes)
        if progress:
            progress()
    return out


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


def wilson(hits: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a proportion."""
    if n == 0:
        return (0.0, 1.0)
    p = hits / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    lo, hi = max(0.0, centre - half), min(1.0, centre + half)
    return (min(lo, p), max(hi, p))  # rounding must not leave p outside its own interval


def power(
    pop: Sequence[Sequence[str | None]],
    sizes: Sequence[int],
    runs: int,
    alpha: float = 0.05,
    seed: int = 0,
    correction: Correction = "holm",
) -> list[dict[str, Any]]:
    """Per study size: each test's power (share of significant draws) with its 95% interval.

    Significant: the test's p, adjusted by `correction` over the draw's defined tests, < α.
    """
    rng = np.random.default_rng(seed)
    result = []
    for n in sizes:
        hits = {t: 0 for t in TESTS}
        for _ in range(runs):
            study = [pop[i] for i in rng.integers(0, len(pop), n)]
            raw = {t: p for t, p in p_values(study).items() if not math.isnan(p)}
            for test, p in zip(raw, adjust(list(raw.values()), correction), strict=True):
                hits[test] += bool(p < alpha)  # an untestable (nan) test is never significant
        result.append({
            "participants": n,
            "runs": runs,
            "power": {t: hits[t] / runs for t in TESTS},
            "ci95": {t: list(wilson(hits[t], runs)) for t in TESTS},
        })
    return result


def draw(doc: dict[str, Any]) -> Figure:
    """Power against N for every test, with the Monte-Carlo intervals; the legend under the axes.

    The legend sits outside the axes, so it never hides a point (power is anywhere in [0, 1]);
    the tests' points at one N are drawn slightly apart (1 % of the N range) so none hides
    another's interval.
    """
    from services.analysis.figures import pyplot

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.6), layout="constrained")
    sizes = [r["participants"] for r in doc["results"]]
    step = 0.01 * ((max(sizes) - min(sizes)) or max(sizes))  # side by side at each N
    for k, test in enumerate(TESTS):
        y = [r["power"][test] for r in doc["results"]]
        lo = [r["power"][test] - r["ci95"][test][0] for r in doc["results"]]
        hi = [r["ci95"][test][1] - r["power"][test] for r in doc["results"]]
        x = [n + (k - (len(TESTS) - 1) / 2) * step for n in sizes]
        ax.errorbar(x, y, yerr=[lo, hi], marker="o", capsize=3, label=test.replace("_", " "))
    ax.axhline(0.8, color="grey", lw=0.8, ls="--")
    ax.set_xlabel("participants")
    how = {"holm": ", Holm", "bonferroni": ", Bonferroni"}.get(doc.get("correction", "none"), "")
    ax.set_ylabel(f"power (α = {doc['alpha']}{how})")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title("Stuart–Maxwell power, simulated cohort (a model)", fontsize=10)
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
