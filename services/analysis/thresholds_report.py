"""The bifurcation thresholds of Sec 4.3 as a JSON-ready report and a readable table."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

from services.model.dynamics import PairParams
from services.model.thresholds import thresholds


def thresholds_report(p: PairParams) -> dict[str, Any]:
    """u, u* = d / (α + γλ) per adjacency eigenvalue λ, u_d* (λ_min), origin eigenvalues.

    All numbers come from `services.model.thresholds.thresholds`; `u_star` is null for an
    eigenvalue with α + γλ ≤ 0 (no bifurcation along that mode).
    """
    th = thresholds(p)
    return {
        "u": th.u,
        "u_d_star": th.u_d_star,
        "adjacency_eigenvalues": list(th.adjacency_eigenvalues),
        "u_star": [
            {"lambda": lam, "u_star": us}
            for lam, us in zip(th.adjacency_eigenvalues, th.u_star, strict=True)
        ],
        "origin_jacobian_eigenvalues": list(th.origin_jacobian_eigenvalues),
        "dissensus_regime": th.dissensus_regime,
        "params": asdict(p),
    }


def format_thresholds(report: dict[str, Any]) -> str:
    """A plain-text table of `thresholds_report`'s numbers."""

    def num(v: float | None) -> str:
        return "—" if v is None else f"{v:.6g}"

    lines = [
        f"attention u                 {num(report['u'])}",
        f"dissensus threshold u_d*    {num(report['u_d_star'])}  (u* at λ_min, Sec 4.3)",
        "",
        "  λ (adjacency)    u* = d/(α+γλ)",
    ]
    lines += [f"  {num(row['lambda']):>13}    {num(row['u_star'])}" for row in report["u_star"]]
    eig = ", ".join(num(v) for v in report["origin_jacobian_eigenvalues"])
    regime = "yes" if report["dissensus_regime"] else "no"
    lines += [
        "",
        f"Jacobian eigenvalues at the origin (eq 3):  {eig}",
        f"dissensus regime (u > u_d* and γ < 0):      {regime}",
    ]
    return "\n".join(lines)
