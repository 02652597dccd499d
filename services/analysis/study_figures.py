"""Figures 8a-8d (PNG, PDF or SVG) of the study analysis (Secs 7-8), and the option shares.

`fig_option_shares`: per trial, the share of humans who pressed each option (stacked, in the
options' colours, for any number of options), with the consensus trials' "both on O" and the
control trials' "robot elsewhere" counts above the bars.

Everything here draws the JSON document of services.analysis.study.analyze_study; no number is
computed twice. Each figure has a `draw_*` that returns the matplotlib Figure (the tests measure
its text) and is saved by `write_figures`. The layouts scale with the number of participants:
Fig 8c wraps participants into side-by-side blocks (and drops the cell letters when the cells
get small), and Figs 8b-8d keep every label clear of the others. matplotlib is imported lazily
with the Agg backend.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from services.analysis.figures import FORMATS, pyplot
from services.analysis.multiplicity import NAMES
from services.analysis.study import CONTROL_TRIALS, OUTCOMES
from services.scene.option_colours import GREY_HEX, hex_of

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

COLOURS: Mapping[str, str] = {
    "C": "#2e7d32",
    "CH": "#9ccc65",
    "D": "#c62828",
    "DH": "#ff8f00",
    "none": "#9e9e9e",
}
TITLES: Mapping[str, str] = {
    "8a": "Outcome frequency per trial",
    "8b": "Control → experiment flows",
    "8c": "Per-participant outcomes",
    "8d": "Contingency table",
    "shares": "Option pressed by the human per trial",
}
FIGURES: Mapping[str, str] = {
    "8a": "fig8a_frequencies",
    "8b": "fig8b_flows",
    "8c": "fig8c_grid",
    "8d": "fig8d_contingency",
    "shares": "fig_option_shares",
}
# Fig 8c: participants per block before the next block starts beside it, and at most how many
# blocks side by side (beyond that the rows get shorter and only every k-th id is written).
GRID_ROWS = 40
GRID_BLOCKS = 5
GRID_HEIGHT_IN = 6.0  # the tallest the cells of one block may get together


def _title(ax: Axes, key: str) -> None:
    """The panel letter (a-d, as Fig 8 of the paper) and the panel's title."""
    ax.set_title(f"({key[-1]}) {TITLES[key]}", loc="left", fontsize=10)


def draw_frequencies(doc: Mapping[str, Any]) -> Figure:
    """Fig 8a: per trial, the share of participants with each outcome (grouped bars)."""
    plt = pyplot()
    freq, n = doc["frequencies"], doc["participants"]
    keys = list(OUTCOMES) + (["none"] if any(r["none"] for r in freq.values()) else [])
    fig, ax = plt.subplots(figsize=(8.0, 3.8), dpi=120)
    width = 0.8 / len(keys)
    ax.axvspan(0.5, len(CONTROL_TRIALS) + 0.5, color="#eeeeee", zorder=0)
    for k, key in enumerate(keys):
        xs = [t + (k - (len(keys) - 1) / 2) * width for t in doc["trials"]]
        ys = [100.0 * freq[str(t)][key] / n for t in doc["trials"]]
        label = "timeout / missing" if key == "none" else key
        ax.bar(xs, ys, width, color=COLOURS[key], label=label, zorder=2)
    ax.set_xticks(doc["trials"])
    ax.set_xlabel("trial (shaded: control)")
    ax.set_ylabel(f"% of {n} participants")
    ax.set_ylim(0, 100)
    ax.set_yticks(range(0, 101, 20))
    _title(ax, "8a")
    # Above the axes, right of the title: a bar at 100 % is never hidden.
    ax.legend(
        ncol=len(keys), fontsize=8, loc="lower right", bbox_to_anchor=(1.0, 1.0),
        frameon=False, borderaxespad=0.2, handlelength=1.2, columnspacing=1.0,
    )
    fig.tight_layout()
    return fig


def _stack(totals: Sequence[int], gap: float) -> dict[int, float]:
    """Bottom y of each non-empty node in a column, C on top."""
    y, out = 0.0, {}
    for i in reversed(range(len(totals))):
        if totals[i] > 0:
            out[i] = y
            y += totals[i] + gap
    return out


def spread(ys: Sequence[float], gap: float, lo: float, hi: float) -> list[float]:
    """Label positions near `ys` (same order), `gap` apart, within [lo, hi] where they fit.

    Sorted top-down, each label is pushed below the one above it; labels pushed under `lo` are
    then pushed back up as a block. Positions already `gap` apart do not move.
    """
    order = sorted(range(len(ys)), key=lambda i: -ys[i])
    out = [0.0] * len(ys)
    prev = math.inf
    for i in order:
        prev = out[i] = min(ys[i], prev - gap, hi)
    floor = lo
    for i in reversed(order):  # bottom-up: lift what fell below the floor
        out[i] = max(out[i], floor)
        floor = out[i] + gap
    return out


def draw_flows(doc: Mapping[str, Any]) -> Figure:
    """Fig 8b: an alluvial plot of control → experiment categories drawn with patches.

    Both columns are centred on the same middle; each flow's count sits at its band's left end
    and the node labels beside their nodes, moved apart (with a leader line) where bands are too
    thin to hold their text.
    """
    plt = pyplot()
    from matplotlib.patches import PathPatch, Rectangle
    from matplotlib.path import Path as MPath

    cont = doc["contingency"]
    table = cont["table"]
    rows, cols = cont["row_totals"], cont["column_totals"]
    total = max(sum(rows), 1)
    gap = 0.04 * total
    left, right = _stack(rows, gap), _stack(cols, gap)
    spans = [max((y + t[i] for i, y in side.items()), default=0.0)
             for side, t in ((left, rows), (right, cols))]
    height = max(spans)
    for column, span in zip((left, right), spans, strict=True):  # centre both columns
        for i in column:
            column[i] += (height - span) / 2
    x0, x1, w = 0.0, 1.0, 0.06
    fig = plt.figure(figsize=(6.0, 4.5), dpi=120)
    ax = fig.add_axes((0.02, 0.1, 0.96, 0.8))
    ax.set_xlim(-0.25, 1.25)
    ax.set_ylim(-gap, height + gap)
    per_point = (height + 2 * gap) / (0.8 * 4.5 * 72)  # data units per typographic point
    out_used = dict.fromkeys(left, 0.0)
    in_used = dict.fromkeys(right, 0.0)
    counts: list[tuple[float, int]] = []  # (band centre at the left end, count)
    for i in sorted(left):  # top-down on both sides, so bands cross no more than needed
        for j in sorted(right):
            c = table[i][j]
            if c <= 0:
                continue
            ly = left[i] + rows[i] - out_used[i]
            ry = right[j] + cols[j] - in_used[j]
            out_used[i] += c
            in_used[j] += c
            xa, xb, xm = x0 + w, x1 - w, (x0 + x1) / 2
            verts = [(xa, ly), (xm, ly), (xm, ry), (xb, ry), (xb, ry - c), (xm, ry - c),
                     (xm, ly - c), (xa, ly - c), (xa, ly)]
            codes = [MPath.MOVETO] + [MPath.CURVE4] * 3 + [MPath.LINETO] + [MPath.CURVE4] * 3
            codes.append(MPath.CLOSEPOLY)
            band = PathPatch(MPath(verts, codes), fc=COLOURS[OUTCOMES[i]], ec="none", alpha=0.45)
            ax.add_patch(band)
            counts.append((ly - c / 2, c))
    _labels(ax, [(y, str(c)) for y, c in counts], x0 + w, x0 + w + 0.03, "left", 7,
            per_point, height)
    for nodes, totals, x, side in ((left, rows, x0, "right"), (right, cols, x1 - w, "left")):
        for i, y in nodes.items():
            ax.add_patch(Rectangle((x, y), w, totals[i], fc=COLOURS[OUTCOMES[i]], ec="black"))
        edge, tx = (x, x - 0.03) if side == "right" else (x + w, x + w + 0.03)
        labels = [(y + totals[i] / 2, f"{OUTCOMES[i]} ({totals[i]})") for i, y in nodes.items()]
        _labels(ax, labels, edge, tx, side, 9, per_point, height)
    ax.axis("off")
    ax.text(x0 + w / 2, -gap, "control (trials 1-3)", ha="center", va="top", fontsize=9)
    ax.text(x1 - w / 2, -gap, "experiment (4-8)", ha="center", va="top", fontsize=9)
    _title(ax, "8b")
    return fig


def _labels(
    ax: Axes, labels: Sequence[tuple[float, str]], edge: float, x: float, ha: str,
    size: float, per_point: float, height: float,
) -> None:
    """Write labels at x near their y, spread apart; a leader line where one had to move."""
    gap = 1.25 * size * per_point
    ys = spread([y for y, _ in labels], gap, gap / 2, height - gap / 2)
    for (y, text), ty in zip(labels, ys, strict=True):
        ax.text(x, ty, text, ha=ha, va="center", fontsize=size)
        if abs(ty - y) > gap / 4:
            ax.plot([edge, x], [y, ty], color="0.4", lw=0.5)


def _grid_layout(n: int) -> tuple[int, int, bool]:
    """Fig 8c's blocks side by side, rows per block, and whether cells carry their letters."""
    blocks = max(1, min(GRID_BLOCKS, math.ceil(n / GRID_ROWS)))
    return blocks, math.ceil(n / blocks), blocks <= 2


def draw_grid(doc: Mapping[str, Any]) -> Figure:
    """Fig 8c: each participant's outcome per trial, coloured by outcome (as Figs 8a-8b).

    A cell that is not as designed (agreement in a control trial, disagreement in an experiment
    trial) gets a black frame; grey marks a timeout or a missing trial. Up to 40 participants
    are one block of rows; more are wrapped into blocks side by side (at most 5), so the figure
    stays about a page at any N; from 81 participants the colours alone carry the outcome.
    """
    plt = pyplot()
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch, Rectangle

    grid = doc["grid"]
    names = list(grid)
    trials = doc["trials"]
    keys = [*OUTCOMES, "none"]
    blocks, per_block, letters = _grid_layout(len(names))
    row_in = min(0.16, GRID_HEIGHT_IN / per_block)
    cell_in = 0.30 if letters else 0.11
    id_pt = min(6.0, 0.8 * row_in * 72)
    every = max(1, math.ceil(5.0 / (row_in * 72)))  # write every k-th id when rows are thin
    width = 0.6 + blocks * (len(trials) * cell_in + 0.45)
    fig, axes = plt.subplots(
        1, blocks, squeeze=False, layout="constrained", dpi=120,
        figsize=(width, 1.5 + per_block * row_in),
    )
    cmap = ListedColormap([COLOURS[k] for k in keys]).with_extremes(over="white")
    for b, ax in enumerate(axes[0]):
        chunk = names[b * per_block:(b + 1) * per_block]
        code = [[keys.index(o if o in OUTCOMES else "none") for o in grid[name]] for name in chunk]
        code += [[len(keys)] * len(trials)] * (per_block - len(chunk))  # the last block's tail
        ax.imshow(code, cmap=cmap, vmin=0, vmax=len(keys) - 1, aspect="auto",
                  interpolation="nearest")
        for r, name in enumerate(chunk):
            for c, (trial, o) in enumerate(zip(trials, grid[name], strict=True)):
                if letters:
                    ax.text(c, r, o or "–", ha="center", va="center", fontsize=min(6.0, id_pt))
                expected = ("D", "DH") if trial in CONTROL_TRIALS else ("C", "CH")
                if o is not None and o not in expected:
                    ax.add_patch(Rectangle((c - 0.5, r - 0.5), 1, 1, fill=False, ec="black",
                                           lw=1.2 if letters else 0.8))
        ax.set_xticks(range(len(trials)), [str(t) for t in trials], fontsize=7)
        ax.set_xlabel("trial", fontsize=8)
        shown = range(0, len(chunk), every)
        ax.set_yticks(list(shown), [chunk[r] for r in shown], fontsize=id_pt)
        ax.tick_params(axis="y", length=0, pad=1.5)
        ax.axvline(len(CONTROL_TRIALS) - 0.5, color="black", lw=1)
    _title(axes[0][0], "8c")
    handles = [Patch(fc=COLOURS[k], label="timeout / missing" if k == "none" else k) for k in keys]
    handles.append(Patch(fc="white", ec="black", lw=1.2, label="not as designed"))
    ncol = len(handles) if width >= 5.5 else math.ceil(len(handles) / 2)  # one row if it fits
    fig.legend(handles=handles, loc="outside lower center", ncol=ncol, fontsize=7,
               frameon=False, handlelength=1.2, columnspacing=1.0)
    return fig


def draw_contingency(doc: Mapping[str, Any]) -> Figure:
    """Fig 8d: the control × experiment table as a heatmap, with its Stuart-Maxwell test.

    The test is written under the axis label (placed from the label's own extent, so the two
    never overprint), with the raw and the corrected p.
    """
    plt = pyplot()
    cont = doc["contingency"]
    table = cont["table"]
    fig, ax = plt.subplots(figsize=(4.8, 4.4), dpi=120)
    ax.imshow(table, cmap="Blues", vmin=0)
    top = max(max(r) for r in table) or 1
    for i, row in enumerate(table):
        for j, v in enumerate(row):
            colour = "white" if v > 0.6 * top else "black"
            ax.text(j, i, str(v), ha="center", va="center", color=colour)
    ticks = range(len(OUTCOMES))
    ax.set_xticks(
        ticks, [f"{o}\n({n})" for o, n in zip(OUTCOMES, cont["column_totals"], strict=True)]
    )
    ax.set_yticks(ticks, [f"{o} ({n})" for o, n in zip(OUTCOMES, cont["row_totals"], strict=True)])
    ax.set_xlabel("experiment (trials 4-8)")
    ax.set_ylabel("control (trials 1-3)")
    _title(ax, "8d")
    ax.annotate(
        _sm_figure(doc), xy=(0.5, 0.0), xycoords=ax.xaxis.label, xytext=(0, -4),
        textcoords="offset points", ha="center", va="top", fontsize=8,
    )
    fig.tight_layout()
    return fig


def _sm_figure(doc: Mapping[str, Any]) -> str:
    """Fig 8d's caption line(s): the control-vs-experiment test, raw and adjusted p."""
    t = doc["stuart_maxwell"]["control_vs_experiment"]
    if "error" in t:
        return f"Stuart-Maxwell undefined (n = {t['n']})"
    line = f"Stuart-Maxwell X² = {t['statistic']:.3f}, df = {t['df']}, n = {t['n']}"
    p = f"p = {_p(t['p'])}"
    if doc["correction"] != "none":
        family = len(doc["correction_family"])
        p += f", {NAMES[doc['correction']]}-adjusted p = {_p(t['p_adjusted'])} ({family} tests)"
    return f"{line}\n{p}"


def _p(x: float) -> str:
    return f"{x:.3g}" if x >= 1e-3 else f"{x:.2e}"



def draw_option_shares(doc: Mapping[str, Any]) -> Figure:
    """Per trial, the % of humans pressing each option, and the agreements above the bars."""
    plt = pyplot()
    names, shares, trials = doc["options"], doc["option_shares"], doc["trials"]
    fig, ax = plt.subplots(figsize=(8.0, 3.8), dpi=120)
    bottom = [0.0] * len(trials)
    for name in [*names, "none"]:
        ys = [100.0 * shares[str(t)]["human"][name] / max(1, shares[str(t)]["n"])
              for t in trials]
        label = "no press (timeout)" if name == "none" else name
        ax.bar(trials, ys, 0.7, bottom=bottom, color=GREY_HEX if name == "none" else hex_of(name),
               label=label, edgecolor="white", linewidth=0.5)
        bottom = [b + y for b, y in zip(bottom, ys, strict=True)]
    for t in trials:
        row = shares[str(t)]
        agree = row.get("both_on_o", row.get("robot_not_human", 0))
        ax.text(t, 102, f"{agree}/{row['n']}", ha="center", va="bottom", fontsize=7)
    ax.set_xticks(trials)
    ax.set_ylim(0, 112)
    ax.set_xlabel("trial (1-3: robot elsewhere / n; 4-8: both on O / n)")
    ax.set_ylabel("% of humans pressing")
    ax.set_title(TITLES["shares"], loc="left", fontsize=10)
    ax.legend(ncol=len(names) + 1, fontsize=8, loc="lower right", bbox_to_anchor=(1.0, 1.04),
              frameon=False)
    fig.tight_layout()
    return fig


DRAW: Mapping[str, Callable[[Mapping[str, Any]], Figure]] = {
    "8a": draw_frequencies,
    "8b": draw_flows,
    "8c": draw_grid,
    "8d": draw_contingency,
    "shares": draw_option_shares,
}


def write_figures(
    doc: Mapping[str, Any], out: Path, formats: tuple[str, ...] = ("png",)
) -> dict[str, Path]:
    """Draw Figs 8a-8d and the option shares into `out` in each format; the first format's paths."""
    bad = [f for f in formats if f not in FORMATS]
    if bad or not formats:
        raise ValueError(f"figure formats must be among {', '.join(FORMATS)}, got {formats!r}")
    plt = pyplot()
    out.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    for key, stem in FIGURES.items():
        fig = DRAW[key](doc)
        try:
            for fmt in formats:
                path = out / f"{stem}.{fmt}"
                fig.savefig(path)
                paths.setdefault(key, path)
        finally:
            plt.close(fig)
    return paths
