"""The N_o-option bifurcation points as a JSON-ready report and a readable table."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

from services.model.dynamics import OptionsParams, PairParams
from services.model.thresholds import option_thresholds


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

    def num(v: float | None) -> str:
        return "—" if v is None else f"{v:.6g}"

    lines = [
        f"options N_o                    {report['n_options']}",
        f"attention u                    {num(report['u'])}",
        f"agreement point u_a*           {num(report['u_agreement'])}",
        f"disagreement point u_d*        {num(report['u_disagreement'])}",
        "",
        "  mode          κ (J = −d + uκ)   λ (adjacency)   ×   u* = d/κ   J eigenvalue at u",
    ]
    lines += [
        f"  {m['pattern']:<12}  {num(m['kappa']):>15}   {num(m['adjacency_eigenvalue']):>13}"
        f"   {m['multiplicity']}   {num(m['u_star']):>8}   {num(m['jacobian_eigenvalue']):>17}"
        for m in report["modes"]
    ]
    regime = "yes" if report["dissensus_regime"] else "no"
    lines += ["", f"dissensus regime (u_d* < u, before any agreement point): {regime}"]
    return "\n".join(lines)
