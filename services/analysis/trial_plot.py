"""One trial as the paper's Figs 6–7 show it: the opinions, eq 7's θ and d, and the hand's path.

Panels: (a) ẑ_h, z_r and b_r against time from "go" (z_r on its own axis, on the right: it
stays within tenths where ẑ_h reaches ±8); (b) θ; (c) d; (d) the hand's path over the
table — the buzzer boxes, the commit line, where the human pressed — with the arm's end effector.
Read from the session store (`nod analyze trial --db F --participant P01 --trial K --out DIR`).
A session of N options draws its N boxes, each in its option's colour and labelled by name;
its opinions are vectors the samples table does not hold, and panel (a) says so.
The figure is titled by participant, trial, mode and O (not by the session id); the legends sit
outside the panels, so no trace is hidden under one.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from services.analysis.figures import pyplot
from services.model.geometry import COLOURS, Box, OptionsLayout, TableLayout
from services.scene.option_colours import hex_of
from services.store import Sample, TrialRecord

if TYPE_CHECKING:
    from matplotlib.figure import Figure


ZR_COLOUR = "tab:blue"
OPINION_MIN = 1.0  # ẑ_h and b_r: the left axis spans at least ±1
ZR_MIN = 0.05  # z_r: its axis spans at least ±0.05, so a z_r near 0 is drawn flat, not as noise


def symmetric_limits(
    values: Sequence[float | None], minimum: float, margin: float = 1.1
) -> tuple[float, float]:
    """±(the largest |value| times `margin`), never narrower than ±`minimum`; None, NaN skipped."""
    top = max((abs(v) for v in values if v is not None and v == v), default=0.0)  # v == v: no NaN
    top = max(top * margin, minimum)
    return -top, top


def trial_title(participant: str, trial: TrialRecord) -> str:
    """The figure's title: participant, trial, mode and O, then what happened."""
    option = f", O = {trial.option}" if trial.option else ""
    return (
        f"{participant}, trial {trial.trial} ({trial.mode}{option}): human {trial.human or '-'}, "
        f"robot {trial.robot or '-'}, outcome {trial.outcome or '-'}"
    )


def figure(
    samples: Sequence[Sample],
    trial: TrialRecord,
    layout: TableLayout | OptionsLayout,
    title: str,
    out: Path,
    formats: Sequence[str] = ("png",),
    names: Sequence[str] = COLOURS,
) -> list[Path]:
    """Draw the four panels (`draw`); write one file per format; return their paths."""
    plt = pyplot()
    fig = draw(samples, trial, layout, title, names)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    try:
        for fmt in formats:
            path = out / f"trial{trial.trial}.{fmt}"
            fig.savefig(path, dpi=150)
            paths.append(path)
    finally:
        plt.close(fig)
    return paths


def draw(
    samples: Sequence[Sample], trial: TrialRecord, layout: TableLayout | OptionsLayout,
    title: str, names: Sequence[str] = COLOURS,
) -> Figure:
    """The four panels of one trial as a matplotlib Figure (`names`: an OptionsLayout's)."""
    from matplotlib.patches import Rectangle

    plt = pyplot()
    if not samples:
        raise ValueError(f"trial {trial.trial} has no stored samples to draw")
    t0 = trial.t_go_ns if trial.t_go_ns is not None else samples[0].t_ns
    t = [(s.t_ns - t0) * 1e-9 for s in samples]
    fig = plt.figure(figsize=(10, 6.5))
    grid = fig.add_gridspec(3, 2, width_ratios=(1.5, 1))
    ax_z = fig.add_subplot(grid[0, 0])
    ax_th = fig.add_subplot(grid[1, 0], sharex=ax_z)
    ax_d = fig.add_subplot(grid[2, 0], sharex=ax_z)
    ax_path = fig.add_subplot(grid[:, 1])
    # ẑ_h reaches the observer's ±a (8) and b_r a few units, while z_r stays within tenths: on
    # one axis z_r is a flat line. z_r gets its own axis on the right, scaled to its own range;
    # both axes are symmetric about 0, so one zero line serves both and the sign (> 0 red) reads
    # the same on either side.
    z_h = [s.z_h for s in samples]
    b_r = [s.b_r for s in samples]
    z_r = [s.z_r for s in samples]
    ax_z.plot(t, z_h, label="ẑ_h (observed human)", color="tab:orange", lw=1.2)
    ax_z.plot(t, b_r, label="b_r (robot bias)", color="tab:green", lw=1.2)
    ax_zr = ax_z.twinx()
    ax_zr.plot(t, z_r, label="z_r (robot), right axis", color=ZR_COLOUR, lw=1.4)
    ax_z.set_ylim(*symmetric_limits(z_h + b_r, OPINION_MIN))
    # z_r's extreme at 3/4 of its half-height: not on ẑ_h, which saturates at 1/1.1 of its own.
    ax_zr.set_ylim(*symmetric_limits(z_r, ZR_MIN, margin=4 / 3))
    ax_z.axhline(0, color="grey", lw=0.6)
    ax_z.set_ylabel("ẑ_h, b_r (> 0 red)")
    ax_zr.set_ylabel("z_r (> 0 red)", color=ZR_COLOUR)
    ax_zr.tick_params(axis="y", colors=ZR_COLOUR)
    ax_zr.spines["right"].set_color(ZR_COLOUR)
    handles = [*ax_z.get_lines()[:1], *ax_zr.get_lines(), *ax_z.get_lines()[1:2]]
    ax_z.legend(handles=handles, fontsize=7, loc="lower right", bbox_to_anchor=(1.0, 1.0),
                ncol=3, frameon=False, borderaxespad=0.2)
    ax_th.plot(t, [s.theta for s in samples], ".", ms=3, color="tab:purple")
    ax_th.set_ylabel("θ (rad)")
    ax_d.plot(t, [s.distance for s in samples], ".", ms=3, color="tab:brown")
    ax_d.set_ylabel("d")
    ax_d.set_xlabel("time from go (s)")
    if all(v is None for v in z_h + z_r):  # a table of N boxes: vectors, not these scalars
        ax_z.text(0.5, 0.5, "opinions over the options are vectors: not in the samples table",
                  transform=ax_z.transAxes, ha="center", va="center", fontsize=8, color="grey")
    if isinstance(layout, TableLayout):  # the paper's two buzzers, as Figs 6-7 colour them
        boxes: list[tuple[Box, str, str | None]] = [
            (layout.red, "tab:red", None), (layout.blue, "tab:blue", None)]
    else:
        boxes = [(b, hex_of(n), n) for b, n in zip(layout.boxes, names, strict=True)]
    for box, colour, label in boxes:
        ax_path.add_patch(
            Rectangle((box.x1, box.y1), box.x2 - box.x1, box.y2 - box.y1, color=colour, alpha=0.35)
        )
        if label is not None:
            ax_path.text(*box.center, label, ha="center", va="center", fontsize=7)
    ax_path.axhline(layout.commit.y, color="grey", ls="--", lw=0.8, label="commit line")
    hx = [s.hand_x for s in samples if s.hand_x is not None]
    hy = [s.hand_y for s in samples if s.hand_y is not None]
    ax_path.plot(hx, hy, color="tab:orange", lw=1.2, label="hand")
    if hx:
        ax_path.plot(hx[-1], hy[-1], "o", color="tab:orange", ms=5)
    ex = [s.ee_x for s in samples if s.ee_x is not None]
    ey = [s.ee_y for s in samples if s.ee_y is not None]
    ax_path.plot(ex, ey, color="black", lw=1.0, label="arm")
    ax_path.set_xlim(0, 1)
    ax_path.set_ylim(1, 0)  # image coordinates: y down
    ax_path.set_aspect("equal")
    ax_path.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=3,
                   frameon=False)
    ax_path.set_title("table (camera view)", fontsize=9)
    for ax, letter in zip((ax_z, ax_th, ax_d, ax_path), "abcd", strict=True):
        ax.set_title(f"({letter})", loc="left", fontweight="bold", fontsize=10)  # over no tick
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
