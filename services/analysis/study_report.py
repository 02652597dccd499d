"""Figures 8a-8d (PNG, PDF or SVG) and a Markdown report of the study analysis (Secs 7-8).

Everything here draws or formats the JSON document of services.analysis.study.analyze_study;
no number is computed twice. matplotlib is imported lazily with the Agg backend.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from services.analysis.figures import FORMATS, pyplot
from services.analysis.study import CONTROL_TRIALS, LIKERT_KEYS, OUTCOMES

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
}
FIGURES: Mapping[str, str] = {
    "8a": "fig8a_frequencies",
    "8b": "fig8b_flows",
    "8c": "fig8c_grid",
    "8d": "fig8d_contingency",
}


def _title(ax: Any, key: str) -> None:
    """The panel letter (a-d, as Fig 8 of the paper) and the panel's title."""
    ax.set_title(f"({key[-1]}) {TITLES[key]}", loc="left", fontsize=10)


def plot_frequencies(doc: Mapping[str, Any], path: Path) -> None:
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
    ax.set_ylim(0, 115)
    ax.set_yticks(range(0, 101, 20))
    _title(ax, "8a")
    ax.legend(ncol=len(keys), fontsize=8, loc="upper center")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _stack(totals: list[int], gap: float) -> dict[int, float]:
    """Bottom y of each non-empty node in a column, C on top."""
    y, out = 0.0, {}
    for i in reversed(range(len(totals))):
        if totals[i] > 0:
            out[i] = y
            y += totals[i] + gap
    return out


def plot_flows(doc: Mapping[str, Any], path: Path) -> None:
    """Fig 8b: an alluvial plot of control → experiment categories drawn with patches."""
    plt = pyplot()
    from matplotlib.patches import PathPatch, Rectangle
    from matplotlib.path import Path as MPath

    cont = doc["contingency"]
    table = cont["table"]
    rows, cols = cont["row_totals"], cont["column_totals"]
    total = max(sum(rows), 1)
    gap = 0.04 * total
    left, right = _stack(rows, gap), _stack(cols, gap)
    x0, x1, w = 0.0, 1.0, 0.06
    fig, ax = plt.subplots(figsize=(6.0, 4.5), dpi=120)
    out_used = dict.fromkeys(left, 0.0)
    in_used = dict.fromkeys(right, 0.0)
    # Draw flows top-down on both sides so bands do not cross more than needed.
    for i in sorted(left):
        for j in sorted(right):
            c = table[i][j]
            if c <= 0:
                continue
            ly = left[i] + rows[i] - out_used[i]
            ry = right[j] + cols[j] - in_used[j]
            out_used[i] += c
            in_used[j] += c
            xa, xb, xm = x0 + w, x1 - w, (x0 + x1) / 2
            verts = [
                (xa, ly),
                (xm, ly),
                (xm, ry),
                (xb, ry),
                (xb, ry - c),
                (xm, ry - c),
                (xm, ly - c),
                (xa, ly - c),
                (xa, ly),
            ]
            codes = [MPath.MOVETO] + [MPath.CURVE4] * 3 + [MPath.LINETO] + [MPath.CURVE4] * 3
            codes.append(MPath.CLOSEPOLY)
            band = PathPatch(MPath(verts, codes), fc=COLOURS[OUTCOMES[i]], ec="none", alpha=0.45)
            ax.add_patch(band)
            ax.text(xa + 0.02, ly - c / 2, str(c), ha="left", va="center", fontsize=7)
    for nodes, totals, x, side in ((left, rows, x0, "right"), (right, cols, x1 - w, "left")):
        for i, y in nodes.items():
            ax.add_patch(Rectangle((x, y), w, totals[i], fc=COLOURS[OUTCOMES[i]], ec="black"))
            tx = x - 0.02 if side == "right" else x + w + 0.02
            ax.text(
                tx,
                y + totals[i] / 2,
                f"{OUTCOMES[i]} ({totals[i]})",
                va="center",
                ha=side,
                fontsize=9,
            )
    height = max(sum(rows), sum(cols)) + gap * len(OUTCOMES)
    ax.set_xlim(-0.25, 1.25)
    ax.set_ylim(-gap, height)
    ax.axis("off")
    ax.text(x0 + w / 2, height, "control (trials 1-3)", ha="center", va="top", fontsize=9)
    ax.text(x1 - w / 2, height, "experiment (4-8)", ha="center", va="top", fontsize=9)
    _title(ax, "8b")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_grid(doc: Mapping[str, Any], path: Path) -> None:
    """Fig 8c: each participant's outcome per trial, coloured by outcome (as Figs 8a-8b).

    A cell that is not as designed (agreement in a control trial, disagreement in an
    experiment trial) gets a black frame; grey marks a timeout or a missing trial.
    """
    plt = pyplot()
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Rectangle

    grid = doc["grid"]
    names = list(grid)
    keys = [*OUTCOMES, "none"]
    code = [[keys.index(o if o in OUTCOMES else "none") for o in grid[name]] for name in names]
    fig, ax = plt.subplots(figsize=(5.5, 1.4 + 0.22 * len(names)), dpi=120)
    cmap = ListedColormap([COLOURS[k] for k in keys])
    ax.imshow(code, cmap=cmap, vmin=0, vmax=len(keys) - 1, aspect="auto", interpolation="nearest")
    for r, name in enumerate(names):
        for c, (trial, o) in enumerate(zip(doc["trials"], grid[name], strict=True)):
            ax.text(c, r, o or "–", ha="center", va="center", fontsize=6)
            expected = ("D", "DH") if trial in CONTROL_TRIALS else ("C", "CH")
            if o is not None and o not in expected:
                ax.add_patch(Rectangle((c - 0.5, r - 0.5), 1, 1, fill=False, ec="black", lw=1.2))
    ax.set_xticks(range(len(doc["trials"])), [str(t) for t in doc["trials"]])
    ax.set_yticks(range(len(names)), names, fontsize=6)
    ax.axvline(len(CONTROL_TRIALS) - 0.5, color="black", lw=1)
    ax.set_xlabel("trial (framed: not as designed)")
    _title(ax, "8c")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_contingency(doc: Mapping[str, Any], path: Path) -> None:
    """Fig 8d: the control × experiment table as a heatmap, with its Stuart-Maxwell test."""
    plt = pyplot()
    table = doc["contingency"]["table"]
    fig, ax = plt.subplots(figsize=(4.8, 4.2), dpi=120)
    ax.imshow(table, cmap="Blues", vmin=0)
    top = max(max(r) for r in table) or 1
    for i, row in enumerate(table):
        for j, v in enumerate(row):
            ax.text(
                j, i, str(v), ha="center", va="center", color="white" if v > 0.6 * top else "black"
            )
    ticks = range(len(OUTCOMES))
    ax.set_xticks(
        ticks,
        [f"{o}\n({n})" for o, n in zip(OUTCOMES, doc["contingency"]["column_totals"], strict=True)],
    )
    ax.set_yticks(
        ticks,
        [f"{o} ({n})" for o, n in zip(OUTCOMES, doc["contingency"]["row_totals"], strict=True)],
    )
    ax.set_xlabel("experiment (trials 4-8)")
    ax.set_ylabel("control (trials 1-3)")
    _title(ax, "8d")
    ax.text(0.5, -0.22, _sm_short(doc["stuart_maxwell"]["control_vs_experiment"]),
            transform=ax.transAxes, ha="center", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def write_figures(
    doc: Mapping[str, Any], out: Path, formats: tuple[str, ...] = ("png",)
) -> dict[str, Path]:
    """Draw Figs 8a-8d into `out` in each format; return the first format's paths by figure."""
    bad = [f for f in formats if f not in FORMATS]
    if bad or not formats:
        raise ValueError(f"figure formats must be among {', '.join(FORMATS)}, got {formats!r}")
    out.mkdir(parents=True, exist_ok=True)
    draw = {"8a": plot_frequencies, "8b": plot_flows, "8c": plot_grid, "8d": plot_contingency}
    paths: dict[str, Path] = {}
    for fmt in formats:
        for key, stem in FIGURES.items():
            path = out / f"{stem}.{fmt}"
            draw[key](doc, path)
            paths.setdefault(key, path)
    return paths


def _num(x: float | None, digits: int = 4) -> str:
    if x is None:
        return "–"
    if x != 0 and (abs(x) < 1e-3 or abs(x) >= 1e5):
        return f"{x:.{digits - 1}e}"
    return f"{x:.{digits}g}"


def _sm_short(t: Mapping[str, Any]) -> str:
    if "error" in t:
        return f"Stuart-Maxwell undefined (n = {t['n']})"
    return f"X² = {t['statistic']:.3f}, df = {t['df']}, p = {_num(t['p'], 3)} (n = {t['n']})"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(r) + " |" for r in rows]


def markdown(doc: Mapping[str, Any], figures: Mapping[str, Path] | None = None) -> str:
    """The Markdown report: data, figures and every statistic of the JSON document."""
    n = doc["participants"]
    md = ["# Study report (paper Secs 7-8, Fig 8)", ""]
    md.append(
        f"{n} participants; control = trials {doc['control_trials']}, experiment = trials "
        f"{doc['experiment_trials']}."
    )
    for note in doc["notes"]:
        md.append(f"- note: {note}")
    ex = doc["excluded_trials"]
    md += ["", f"Excluded from the categorical tests: {len(ex)} trial(s) without an outcome."]
    md += [f"- {e['participant']} trial {e['trial']}: {e['reason']}" for e in ex]
    if doc["contingency"]["excluded_participants"]:
        md.append(
            "- no phase category (left out of the contingency table): "
            + ", ".join(doc["contingency"]["excluded_participants"])
        )
    if figures:
        md += ["", "## Figures", ""]
        md += [f"![Fig {k}: {TITLES[k]}]({p.name})\n" for k, p in figures.items()]
    md += ["", "## Frequencies per trial (Fig 8a)", ""]
    md += _table(
        ["trial", *OUTCOMES, "none", "n"],
        [
            [t, *(f"{r[o]} ({100 * r[o] / n:.2f}%)" for o in OUTCOMES), str(r["none"]), str(r["n"])]
            for t, r in doc["frequencies"].items()
        ],
    )
    cont = doc["contingency"]
    md += ["", "## Contingency table, control (rows) × experiment (columns) (Fig 8d)", ""]
    md += _table(
        ["control \\ experiment", *OUTCOMES, "total"],
        [
            [o, *(str(v) for v in row), str(tot)]
            for o, row, tot in zip(OUTCOMES, cont["table"], cont["row_totals"], strict=True)
        ]
        + [["total", *(str(v) for v in cont["column_totals"]), str(sum(cont["row_totals"]))]],
    )
    md += [
        "",
        "Flows (Fig 8b): "
        + (", ".join(f"{f['from']}→{f['to']} {f['count']}" for f in doc["flows"]) or "none"),
    ]
    md += ["", "## Stuart-Maxwell tests of marginal homogeneity", ""]
    rows = []
    for name, t in doc["stuart_maxwell"].items():
        label = name.replace("_", " ").replace("vs", "→").replace("trial ", "trials ")
        if "error" in t:
            rows.append([label, str(t["n"]), "–", "–", "–", "–", t["error"]])
        else:
            rows.append(
                [
                    label,
                    str(t["n"]),
                    f"{t['statistic']:.4f}",
                    str(t["df"]),
                    _num(t["p"]),
                    " ".join(t["categories_kept"]),
                    "",
                ]
            )
    md += _table(["comparison", "n", "X²", "df", "p", "categories kept", "note"], rows)
    q = doc["questionnaire"]
    md += ["", f"## Questionnaire (Sec 8), {q['n']} answer sets", ""]
    rows = []
    for key in LIKERT_KEYS:
        t = q[key]
        rows.append(
            [
                key.upper(),
                str(t["n"]),
                _num(t.get("mean")),
                _num(t.get("sd")),
                _num(t.get("t")),
                str(t.get("df", "–")),
                _num(t.get("p")),
                _num(t.get("cohens_d")),
                t.get("error", ""),
            ]
        )
    md += _table(
        ["question", "n", "mean", "sd", "t (vs 5.5)", "df", "p", "Cohen's d", "note"], rows
    )
    q3 = q["q3"]
    counts = ", ".join(f"{k} {v}" for k, v in q3["counts"].items())
    md += [
        "",
        f"Q3 ({counts}): "
        + (
            q3["error"]
            if "error" in q3
            else f"χ² = {q3['chi2']:.4f}, df = {q3['df']}, p = {_num(q3['p'])}, Cohen's w = "
            f"{q3['cohens_w']:.4f}, Cramér's V = {q3['cramers_v']:.4f}"
        ),
    ]
    if doc["sessions_without_questionnaire"]:
        md.append("\nNo questionnaire yet: " + ", ".join(doc["sessions_without_questionnaire"]))
    if doc["questionnaire_without_session"]:
        md.append(
            "\nQuestionnaire without a session: " + ", ".join(doc["questionnaire_without_session"])
        )
    md += [
        "",
        "## Method",
        "",
        "Phase category = most frequent outcome of the phase's trials, ties to the later "
        "trial; timeouts and missing trials are excluded from every categorical test. "
        "Stuart-Maxwell drops categories empty in both margins. t-tests are one-sample, "
        "two-sided, against 5.5; Cohen's d = (mean − 5.5)/sd; Q3 χ² against uniform with "
        "Cohen's w = √(χ²/n) and Cramér's V = √(χ²/(2n)).",
        "",
    ]
    return "\n".join(md)


def summary(doc: Mapping[str, Any]) -> str:
    """A few lines for the terminal."""
    lines = [
        f"{doc['participants']} participants, "
        f"{len(doc['excluded_trials'])} trial(s) excluded (timeout/missing)"
    ]
    for t, r in doc["frequencies"].items():
        lines.append(
            f"  trial {t}: "
            + "  ".join(f"{o} {r[o]:>2}" for o in OUTCOMES)
            + (f"  none {r['none']}" if r["none"] else "")
        )
    for name, t in doc["stuart_maxwell"].items():
        lines.append(f"  {name}: {_sm_short(t)}")
    q = doc["questionnaire"]
    if q["n"] == 0:
        lines.append("  questionnaire: no answers stored (enter them with `nod questionnaire`)")
        return "\n".join(lines)
    for key in LIKERT_KEYS:
        t = q[key]
        lines.append(
            f"  {key}: "
            + (
                t["error"]
                if "error" in t
                else f"mean {t['mean']:.2f}, t = {t['t']:.3f}, p = {_num(t['p'], 3)}, "
                f"d = {t['cohens_d']:.3f}"
            )
        )
    q3 = q["q3"]
    lines.append(
        "  q3: "
        + (
            q3["error"]
            if "error" in q3
            else f"χ² = {q3['chi2']:.3f}, p = {_num(q3['p'], 3)}, w = {q3['cohens_w']:.3f}"
        )
    )
    return "\n".join(lines)


def finite_json(value: Any) -> Any:
    """Replace non-finite floats by None so the document is strict JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite_json(v) for v in value]
    return value
