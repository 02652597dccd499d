"""`nod fit`'s figures, drawn from its JSON document (no number is computed twice).

`fit_intervals`: one panel per identifiable parameter, every participant's estimate with its
90 % interval. `fit_predictive`: per participant, the observed outcome shares next to those of
sessions simulated from their posterior, and the observed press times over the simulated ones.
matplotlib with the Agg backend (`services.analysis.figures`), imported on first use.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from services.analysis.figures import pyplot
from services.analysis.study_figures import COLOURS
from services.fit.report import MEANING, OUTCOME_KEYS

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

FIGURES = {"intervals": "fit_intervals", "predictive": "fit_predictive"}
MIN_SPAN_REL = 0.1  # a linear axis spans at least 10 % of its largest |value|
CHAR_EM = 0.55  # a character's mean width in DejaVu Sans, in ems (a little over, to be safe)


def is_probability(est: Sequence[float], low: Sequence[float], high: Sequence[float]) -> bool:
    """A 0/1 parameter: every set is {0}, {1} or {0, 1} and every estimate within [0, 1]."""
    return all(v in (0.0, 1.0) for v in (*low, *high)) and all(0.0 <= e <= 1.0 for e in est)


def value_limits(values: Sequence[float], rel: float = MIN_SPAN_REL) -> tuple[float, float]:
    """Limits around `values` at least `rel` × their largest |value| wide (1 if all are 0).

    Near-constant data (0.9997-1.0, or every interval a point) would otherwise be stretched over
    the whole panel, its rounding noise drawn as if it were a spread between people.
    """
    lo, hi = min(values), max(values)
    need = rel * max(abs(lo), abs(hi)) or 1.0
    if hi - lo >= need:
        pad = 0.06 * (hi - lo)
        return lo - pad, hi + pad
    mid = (lo + hi) / 2
    return mid - need / 2, mid + need / 2


def log_axis(ax: Axes, values: Sequence[float]) -> None:
    """A log y axis for positive values, labelled in plain numbers (10, not 10¹).

    Ticks at 1, 2, 5, 10, … (1, 10, 100, … over more than 2.5 decades); minor ticks unlabelled.
    """
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    ax.set_yscale("log")
    decades = math.log10(max(values) / min(values))
    ax.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0) if decades <= 2.5 else (1.0,)))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))  # 10, not 10¹
    ax.yaxis.set_minor_formatter(NullFormatter())


def wrap(text: str, width_in: float, fontsize: float) -> str:
    """`text` broken into lines that fit `width_in` inches at `fontsize` points."""
    per_line = max(20, int(width_in * 72 / (CHAR_EM * fontsize)))
    return "\n".join(line for part in text.split("\n") for line in textwrap.wrap(part, per_line))


def draw_intervals(doc: Mapping[str, Any]) -> Figure:
    """Every participant's estimate and 90 % interval, one panel per identifiable parameter.

    A 0/1 parameter's panel spans 0 to 1: its most likely value with its set as the bar, and its
    probability as a hollow ring beside them; a parameter the recovery check learnt
    on its log (spanning a decade) is drawn on a log axis; any other axis spans at least
    MIN_SPAN_REL of its values, so near-constant estimates are drawn flat. Long meanings wrap.
    """
    plt = pyplot()
    names: Sequence[str] = doc["identifiable"]
    rows = doc["participants"]
    scales = {c["name"]: c.get("scale") for c in doc.get("check", [])}
    n = max(1, len(names))
    width = max(6.5, 0.18 * len(rows) + 2)
    fig, axes = plt.subplots(n, 1, figsize=(width, 2.1 * n + 0.8), dpi=120, squeeze=False,
                             layout="constrained")
    xs = list(range(len(rows)))
    for ax, name in zip(axes[:, 0], names, strict=False):
        est = [r["parameters"][name]["estimate"] for r in rows]
        low = [r["parameters"][name]["low"] for r in rows]
        high = [r["parameters"][name]["high"] for r in rows]
        # Every estimate lies inside its interval or set (a 0/1 parameter's most likely value in
        # its set); max(0, ·) only guards a rounding's last digit.
        ax.errorbar(xs, est, yerr=[[max(0.0, e - lo) for e, lo in zip(est, low, strict=True)],
                                   [max(0.0, h - e) for e, h in zip(est, high, strict=True)]],
                    fmt="o", ms=3, lw=1, color="#1565c0", ecolor="#90caf9")
        prob = [(x, r["parameters"][name]["probability"]) for x, r in zip(xs, rows, strict=True)
                if "probability" in r["parameters"][name]]
        if prob:
            ax.plot([x for x, _ in prob], [p for _, p in prob], "o", ms=5, mfc="none",
                    mec="#c62828", mew=0.8, label="probability of 1")
            ax.legend(fontsize=6, loc="center right", frameon=False)
        every = [*est, *low, *high]
        if is_probability(est, low, high):
            ax.set_ylim(-0.06, 1.06)
            ax.set_yticks([0.0, 0.5, 1.0])
        elif scales.get(name) == "log" and min(every) > 0:
            log_axis(ax, every)
        elif every:
            ax.set_ylim(*value_limits(every))
        ax.set_ylabel(name, fontsize=8)
        ax.set_title(wrap(MEANING.get(name, name), width - 1.0, 8), loc="left", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_xticks(xs)
        ax.set_xticklabels([r["participant"] for r in rows], rotation=90, fontsize=6)
    if not names:
        axes[0, 0].text(0.5, 0.5, "no parameter is identifiable from these trials",
                        ha="center", va="center", transform=axes[0, 0].transAxes)
    skipped = ", ".join(doc["not_identifiable"]) or "none"
    fig.suptitle(wrap(f"Per-participant estimates, {int(doc['level'] * 100)} % intervals\n"
                      f"not identifiable, not shown: {skipped}", width - 0.4, 9), fontsize=9)
    return fig


def draw_predictive(doc: Mapping[str, Any]) -> Figure:
    """Observed vs simulated outcome shares (stacked bar pairs) and press times per person."""
    plt = pyplot()
    rows = [r for r in doc["participants"] if "predictive" in r]
    width = max(7.0, 0.3 * len(rows) + 2)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(width, 6.0), dpi=120, sharex=True,
                                      layout="constrained")
    title_in = width - 1.5  # the axes' width: less the y labels and the legend on the right
    bar = 0.38
    for i, r in enumerate(rows):
        pred = r["predictive"]
        for offset, key, hatch in ((-bar / 2, "observed", None), (bar / 2, "simulated", "//")):
            bottom_at = 0.0
            for k in OUTCOME_KEYS:
                share = pred[key][k]
                top.bar(i + offset, share, bar, bottom=bottom_at, color=COLOURS[k],
                        hatch=hatch, edgecolor="white", lw=0.3,
                        label=k if i == 0 and key == "observed" else None)
                bottom_at += share
        sim = pred["simulated_press_s"]
        if sim:
            bottom.boxplot([sim], positions=[i + bar / 2], widths=bar * 0.9,
                           showfliers=False, manage_ticks=False)
        obs = pred["observed_press_s"]
        bottom.plot([i - bar / 2] * len(obs), obs, "o", ms=3, color="#c62828")
    top.set_ylabel("share of trials")
    top.set_ylim(0, 1)
    top.set_title(wrap("(a) outcomes: observed (left, plain) | simulated from the fit (right, "
                       "hatched)", title_in, 9), loc="left", fontsize=9)
    top.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    times = [v for r in rows for k in ("observed_press_s", "simulated_press_s")
             for v in r["predictive"][k]]
    if times:  # press times all but equal: drawn flat, not stretched over the panel
        bottom.set_ylim(*value_limits(times))
    bottom.set_ylabel("press time after go (s)")
    bottom.set_title(wrap("(b) press times: observed (dots) | simulated (box: quartiles, "
                          "whiskers)", title_in, 9), loc="left", fontsize=9)
    bottom.set_xticks(range(len(rows)))
    bottom.set_xticklabels([r["participant"] for r in rows], rotation=90, fontsize=6)
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
