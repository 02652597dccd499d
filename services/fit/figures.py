"""`nod fit`'s figures, drawn from its JSON document (no number is computed twice).

`fit_intervals`: one panel per identifiable parameter, every participant's estimate with its
90 % interval. `fit_predictive`: per participant, the observed outcome shares next to those of
sessions simulated from their posterior, and the observed press times over the simulated ones.
matplotlib with the Agg backend (`services.analysis.figures`), imported on first use.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from services.analysis.figures import pyplot
from services.analysis.study_figures import COLOURS
from services.fit.report import MEANING, OUTCOME_KEYS

if TYPE_CHECKING:
    from matplotlib.figure import Figure

FIGURES = {"intervals": "fit_intervals", "predictive": "fit_predictive"}


def draw_intervals(doc: Mapping[str, Any]) -> Figure:
    """Every participant's estimate and 90 % interval, one panel per identifiable parameter."""
    plt = pyplot()
    names: Sequence[str] = doc["identifiable"]
    rows = doc["participants"]
    n = max(1, len(names))
    fig, axes = plt.subplots(n, 1, figsize=(max(6.0, 0.18 * len(rows) + 2), 1.9 * n + 0.6),
                             dpi=120, squeeze=False)
    xs = list(range(len(rows)))
    for ax, name in zip(axes[:, 0], names, strict=False):
        est = [r["parameters"][name]["estimate"] for r in rows]
        low = [r["parameters"][name]["low"] for r in rows]
        high = [r["parameters"][name]["high"] for r in rows]
        # A 0/1 parameter's estimate is a probability and its set {0}, {1} or [0, 1]: the
        # probability may lie outside a one-value set, so its bar is drawn from the point.
        ax.errorbar(xs, est, yerr=[[max(0.0, e - lo) for e, lo in zip(est, low, strict=True)],
                                   [max(0.0, h - e) for e, h in zip(est, high, strict=True)]],
                    fmt="o", ms=3, lw=1, color="#1565c0", ecolor="#90caf9")
        ax.set_ylabel(name, fontsize=8)
        ax.set_title(MEANING.get(name, name), loc="left", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_xticks(xs)
        ax.set_xticklabels([r["participant"] for r in rows], rotation=90, fontsize=6)
    if not names:
        axes[0, 0].text(0.5, 0.5, "no parameter is identifiable from these trials",
                        ha="center", va="center", transform=axes[0, 0].transAxes)
    skipped = ", ".join(doc["not_identifiable"]) or "none"
    fig.suptitle(f"Per-participant estimates, {int(doc['level'] * 100)} % intervals\n"
                 f"not identifiable, not shown: {skipped}", fontsize=9)
    fig.tight_layout()
    return fig


def draw_predictive(doc: Mapping[str, Any]) -> Figure:
    """Observed vs simulated outcome shares (stacked bar pairs) and press times per person."""
    plt = pyplot()
    rows = [r for r in doc["participants"] if "predictive" in r]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(max(7.0, 0.3 * len(rows) + 2), 6.0),
                                      dpi=120, sharex=True)
    width = 0.38
    for i, r in enumerate(rows):
        pred = r["predictive"]
        for offset, key, hatch in ((-width / 2, "observed", None), (width / 2, "simulated", "//")):
            bottom_at = 0.0
            for k in OUTCOME_KEYS:
                share = pred[key][k]
                top.bar(i + offset, share, width, bottom=bottom_at, color=COLOURS[k],
                        hatch=hatch, edgecolor="white", lw=0.3,
                        label=k if i == 0 and key == "observed" else None)
                bottom_at += share
        sim = pred["simulated_press_s"]
        if sim:
            bottom.boxplot([sim], positions=[i + width / 2], widths=width * 0.9,
                           showfliers=False, manage_ticks=False)
        obs = pred["observed_press_s"]
        bottom.plot([i - width / 2] * len(obs), obs, "o", ms=3, color="#c62828")
    top.set_ylabel("share of trials")
    top.set_ylim(0, 1)
    top.set_title("(a) outcomes: observed (left, plain) | simulated from the fit (right, "
                  "hatched)", loc="left", fontsize=9)
    top.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    bottom.set_ylabel("press time after go (s)")
    bottom.set_title("(b) press times: observed (dots) | simulated (box: quartiles, whiskers)",
                     loc="left", fontsize=9)
    bottom.set_xticks(range(len(rows)))
    bottom.set_xticklabels([r["participant"] for r in rows], rotation=90, fontsize=6)
    fig.tight_layout()
    return fig


def write_figures(doc: Mapping[str, Any], out: Path, formats: Sequence[str] = ("png",)
                  ) -> list[Path]:
    """Draw both figures into `out`; the files written."""
    plt = pyplot()
    written = []
    drawers = {"intervals": draw_intervals, "predictive": draw_predictive}
    for key, stem in FIGURES.items():
        if key == "predictive" and not any("predictive" in r for r in doc["participants"]):
            continue
        fig = drawers[key](doc)
        for fmt in formats:
            path = out / f"{stem}.{fmt}"
            fig.savefig(path)
            written.append(path)
        plt.close(fig)
    return written
