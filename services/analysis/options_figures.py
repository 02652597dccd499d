"""The figures of an N_o-option study: Figs 8a-8d as the paper's, and the option shares.

`nod analyze options-study --out DIR` writes Figs 8a-8d with `study_figures.write_figures`
(the N_o-option document has the same keys: the outcome classes do not depend on N_o) and
`fig_option_shares`: per trial, the share of humans who pressed each option (stacked, in the
options' colours), with the consensus trials' "both on O" and the control trials' "robot
elsewhere" marked above the bars. Everything is drawn from the JSON document; matplotlib is
imported lazily with the Agg backend.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from services.analysis.figures import FORMATS, pyplot
from services.analysis.study_figures import write_figures
from services.scene.option_colours import COLOURS

if TYPE_CHECKING:
    from matplotlib.figure import Figure

_GREY = "#9e9e9e"


def _hex(name: str) -> str:
    if name not in COLOURS:
        return _GREY
    b, g, r = COLOURS[name][0]
    return f"#{r:02x}{g:02x}{b:02x}"


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
        ax.bar(trials, ys, 0.7, bottom=bottom, color=_GREY if name == "none" else _hex(name),
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
    ax.set_title("Option pressed by the human per trial", loc="left", fontsize=10)
    ax.legend(ncol=len(names) + 1, fontsize=8, loc="lower right", bbox_to_anchor=(1.0, 1.04),
              frameon=False)
    fig.tight_layout()
    return fig


def write_options_figures(
    doc: Mapping[str, Any], out: Path, formats: tuple[str, ...] = ("png",)
) -> dict[str, Path]:
    """Figs 8a-8d and the option shares into `out`; the first format's paths by figure."""
    paths = write_figures(doc, out, formats)
    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise ValueError(f"figure formats must be among {', '.join(FORMATS)}, got {formats!r}")
    plt = pyplot()
    fig = draw_option_shares(doc)
    try:
        for fmt in formats:
            path = out / f"fig_option_shares.{fmt}"
            fig.savefig(path)
            paths.setdefault("shares", path)
    finally:
        plt.close(fig)
    return paths
