"""The bifurcation thresholds as a JSON-ready report and a readable table, for any N_o options.

`report` picks: the paper's two options with β = δ = 0 are Sec 4.3's report (`thresholds_report`,
u* per adjacency eigenvalue, as the paper states them); any other table is the N_o-option report
(`options_thresholds_report`: every mode of the zero-sum subspace), whose two-option numbers are
the same (`services.model.thresholds` checks its kernel against the general form).
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

from services.model.dynamics import OptionsParams, PairParams
from services.model.thresholds import option_thresholds, thresholds


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


def _num(v: float | None) -> str:
    """A number of the plain-text tables: six significant digits, a dash where none exists."""
    return "—" if v is None else f"{v:.6g}"


def format_thresholds(report: dict[str, Any]) -> str:
    """A plain-text table of `thresholds_report`'s numbers."""
    lines = [
        f"attention u                 {_num(report['u'])}",
        f"dissensus threshold u_d*    {_num(report['u_d_star'])}  (u* at λ_min, Sec 4.3)",
        "",
        "  λ (adjacency)    u* = d/(α+γλ)",
    ]
    lines += [f"  {_num(row['lambda']):>13}    {_num(row['u_star'])}" for row in report["u_star"]]
    eig = ", ".join(_num(v) for v in report["origin_jacobian_eigenvalues"])
    regime = "yes" if report["dissensus_regime"] else "no"
    lines += [
        "",
        f"Jacobian eigenvalues at the origin (eq 3):  {eig}",
        f"dissensus regime (u > u_d* and γ < 0):      {regime}",
    ]
    return "\n".join(lines)


def options_thresholds_report(
    pair: PairParams, n_options: int, beta: float = 0.0, delta: float = 0.0
) -> dict[str, Any]:
    """u, the agreement and disagreement points, and every mode with the eigenvalues behind it.

    Each mode: κ (eigenvalue of K on the zero-sum subspace, J = −d I + u K), the adjacency
    eigenvalue λ it comes from, its multiplicity, u* = d/κ (null when κ ≤ 0) and the Jacobian's
    eigenvalue −d + u κ at the neutral point. Numbers from
    `services.model.thresholds.option_thresholds`.
    """
    p = OptionsParams(pair=pair, n_options=n_options, beta=beta, delta=delta)
    th = option_thresholds(p)
    return {
        "n_options": th.n_options,
        "u": th.u,
        "d": th.d,
        "u_agreement": th.u_agreement,
        "u_disagreement": th.u_disagreement,
        "modes": [asdict(m) for m in th.modes],
        "dissensus_regime": th.dissensus_regime,
        "params": {"pair": asdict(pair), "beta": beta, "delta": delta},
    }


def format_options_thresholds(report: dict[str, Any]) -> str:
    """A plain-text table of `options_thresholds_report`'s numbers."""
    lines = [
        f"options N_o                    {report['n_options']}",
        f"attention u                    {_num(report['u'])}",
        f"agreement point u_a*           {_num(report['u_agreement'])}",
        f"disagreement point u_d*        {_num(report['u_disagreement'])}",
        "",
        "  mode          κ (J = −d + uκ)   λ (adjacency)   ×   u* = d/κ   J eigenvalue at u",
    ]
    lines += [
        f"  {m['pattern']:<12}  {_num(m['kappa']):>15}   {_num(m['adjacency_eigenvalue']):>13}"
        f"   {m['multiplicity']}   {_num(m['u_star']):>8}   {_num(m['jacobian_eigenvalue']):>17}"
        for m in report["modes"]
    ]
    regime = "yes" if report["dissensus_regime"] else "no"
    lines += ["", f"dissensus regime (u_d* < u, before any agreement point): {regime}"]
    return "\n".join(lines)


def report(
    pair: PairParams, n_options: int = 2, beta: float = 0.0, delta: float = 0.0
) -> tuple[dict[str, Any], str]:
    """The thresholds of a table of `n_options` as (JSON-ready report, its readable table)."""
    if n_options == 2 and beta == 0.0 and delta == 0.0:
        doc = thresholds_report(pair)
        return doc, format_thresholds(doc)
    doc = options_thresholds_report(pair, n_options, beta, delta)
    return doc, format_options_thresholds(doc)
