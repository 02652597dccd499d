"""Figures 3a (bias sweep) and 3b (nullclines and equilibria) as PNG files.

matplotlib is imported lazily with the non-interactive Agg backend, so the analysis library
and the `nod analyze` commands that draw nothing never pay for it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from services.analysis.equilibria import Equilibrium, box, deltas, find_equilibria
from services.analysis.figures import pyplot
from services.analysis.sweep import SweepResult
from services.model.dynamics import PairParams

_MARKERS = {
    "stable": dict(marker="o", color="black", markerfacecolor="black"),
    "unstable": dict(marker="o", color="black", markerfacecolor="white"),
    "saddle": dict(marker="X", color="crimson", markerfacecolor="crimson"),
    "non-hyperbolic": dict(marker="D", color="purple", markerfacecolor="white"),
}


def plot_sweep(result: SweepResult, path: str | Path, u: float) -> None:
    """Fig 3a: the consensus map over (b_r, b_h), consensus yellow and dissensus blue.

    The square of half-side u is dashed in white; grid points that did not reach a steady state
    are marked with red dots.
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 5.0), dpi=120)
    db_r = (result.b_r[-1] - result.b_r[0]) / max(result.b_r.size - 1, 1)
    db_h = (result.b_h[-1] - result.b_h[0]) / max(result.b_h.size - 1, 1)
    extent = (
        result.b_r[0] - db_r / 2,
        result.b_r[-1] + db_r / 2,
        result.b_h[0] - db_h / 2,
        result.b_h[-1] + db_h / 2,
    )
    ax.imshow(
        result.consensus.astype(float),
        origin="lower",
        extent=extent,
        cmap="viridis",
        vmin=0.0,
        vmax=1.0,
        interpolation="nearest",
        aspect="auto",
    )
    ax.plot([-u, u, u, -u, -u], [-u, -u, u, u, -u], "w--", lw=1.2, label=f"|b| = u = {u:g}")
    if not result.converged.all():
        BR, BH = np.meshgrid(result.b_r, result.b_h)
        bad = ~result.converged
        ax.plot(BR[bad], BH[bad], "r.", ms=3, label="not settled")
    ax.set_xlabel("robot bias $b_r$")
    ax.set_ylabel("human bias $b_h$")
    ax.set_title("consensus (yellow) vs dissensus (blue)")
    ax.legend(loc="upper left", fontsize=7, framealpha=0.6)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _draw_nullclines(
    ax: Any, b_r: float, b_h: float, p: PairParams, equilibria: list[Equilibrium], title: str
) -> None:
    """Δ1 = 0 and Δ2 = 0 (eqs 4-5) in the (z_r, z_h) plane on `ax`, every equilibrium marked."""
    zr_half, zh_half = box(b_r, b_h, p)
    zr = np.linspace(-1.15 * zr_half, 1.15 * zr_half, 500)
    zh = np.linspace(-1.15 * zh_half, 1.15 * zh_half, 500)
    ZR, ZH = np.meshgrid(zr, zh)
    d1, d2 = deltas(ZR, ZH, b_r, b_h, p)
    ax.contour(ZR, ZH, d1, levels=[0.0], colors="tab:blue", linewidths=1.5)
    ax.contour(ZR, ZH, d2, levels=[0.0], colors="tab:red", linewidths=1.5)
    ax.plot([], [], color="tab:blue", label=r"$\Delta_1 = 0$ (eq 4)")
    ax.plot([], [], color="tab:red", label=r"$\Delta_2 = 0$ (eq 5)")
    seen: set[str] = set()
    for e in equilibria:
        label = None if e.stability in seen else e.stability
        seen.add(e.stability)
        ax.plot(e.z_r, e.z_h, ls="none", ms=8, label=label, **_MARKERS[e.stability])
    ax.axhline(0.0, color="grey", lw=0.5)
    ax.axvline(0.0, color="grey", lw=0.5)
    ax.set_xlabel("robot opinion $z_r$")
    ax.set_ylabel("human opinion $z_h$")
    ax.set_title(title, loc="left", fontsize=10)
    ax.legend(loc="best", fontsize=7)


def plot_nullclines(
    b_r: float, b_h: float, p: PairParams, equilibria: list[Equilibrium], path: str | Path
) -> None:
    """Zero contours of Δ1 and Δ2 (eqs 4-5) at one pair of biases, equilibria marked.

    Filled: stable; cross: saddle; open: unstable.
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 5.0), dpi=120)
    _draw_nullclines(ax, b_r, b_h, p, equilibria, f"nullclines at $b_r$ = {b_r:g}, $b_h$ = {b_h:g}")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_nullcline_pair(p: PairParams, offset: float, path: str | Path) -> list[list[Equilibrium]]:
    """Fig 3b: the nullclines at b_r = b_h = +(u + offset) and at −(u + offset), side by side.

    u is the robot's attention u_r (the paper's Fig 3b uses u + 1 with u = 2.24). Returns the
    equilibria of each panel, as drawn.
    """
    plt = pyplot()
    b = p.robot.u + offset
    fig, axes = plt.subplots(1, 2, figsize=(10.5, 5.0), dpi=120)
    found = []
    for ax, letter, bias in zip(axes, "ab", (b, -b), strict=True):
        eqs = find_equilibria(bias, bias, p)
        found.append(eqs)
        title = f"({letter}) $b_r = b_h = {bias:+.4g}$ ({'+' if bias > 0 else '−'}(u + {offset:g}))"
        _draw_nullclines(ax, bias, bias, p, eqs, title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return found
