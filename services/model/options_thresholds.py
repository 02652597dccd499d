"""Agreement and disagreement bifurcation points of the N_o-option pair (docs/multi-option.md).

At the neutral point Z = 0 with no bias, the Jacobian of the N_o-option dynamics
(`services.model.dynamics.network_jacobian`) restricted to the zero-sum subspace is

    J(u) = −d I + u K,    K = (α − β) I + (γ − δ) A ⊗ I_{N_o−1}

(on zero-sum vectors Σ_{l≠j} z_l = −z_j, which turns β and δ into −β, −δ). It is affine in u,
so each eigenvalue κ of K with κ > 0 gives a bifurcation point u* = d / κ where −d + u κ crosses
zero; κ ≤ 0 gives none. The eigenvector says which kind: the robot's and the human's parts
point the same way (agreement: both lean to the same options) or opposite ways (disagreement).
With the paper's A (λ = ±1) and β = δ = 0 this is Sec 4.3's u* = d/(α + γλ) for every N_o, each
mode N_o − 1 times over.

Everything is computed numerically from `network_jacobian` (not from the formula above, which
the tests check it against). Like `services.model.dynamics.thresholds`, the analysis is the
homogeneous pair's: both agents take the robot's (d, u, α, γ).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from services.model.dynamics import OptionsParams, PairParams, network_jacobian, subspace_basis

Pattern = Literal["agreement", "disagreement", "mixed"]
_TOL = 1e-9  # eigenvalues closer than this (relative) are one mode counted with multiplicity


@dataclass(frozen=True, slots=True)
class Mode:
    """One eigenvalue of K on the zero-sum subspace, with what it means."""

    pattern: Pattern  # how the robot's and the human's parts of the eigenvector relate
    kappa: float  # the eigenvalue of K: J's eigenvalue is −d + u κ
    adjacency_eigenvalue: float | None  # λ with κ = (α − β) + (γ − δ) λ; None when γ = δ
    multiplicity: int
    u_star: float | None  # d / κ, None when κ ≤ 0 (no bifurcation along this mode)
    jacobian_eigenvalue: float  # −d + u κ at the parameters' u


@dataclass(frozen=True, slots=True)
class OptionThresholds:
    """The bifurcation points of the homogeneous pair over N_o options."""

    n_options: int
    u: float
    d: float
    modes: tuple[Mode, ...]  # sorted by κ
    u_agreement: float | None  # the smallest u* of an agreement mode
    u_disagreement: float | None  # the smallest u* of a disagreement mode (u_d*)

    @property
    def dissensus_regime(self) -> bool:
        """Whether u is past u_d* and before any agreement point: the unbiased pair disagrees."""
        if self.u_disagreement is None or self.u <= self.u_disagreement:
            return False
        return self.u_agreement is None or self.u_disagreement < self.u_agreement


def homogeneous(p: OptionsParams) -> OptionsParams:
    """The same network with both agents taking the robot's parameters (the paper's analysis)."""
    r = p.pair.robot
    return replace(p, pair=PairParams(robot=r, human=r, a_rh=p.pair.a_rh, a_hr=p.pair.a_hr))


def restricted_jacobian(p: OptionsParams, z: np.ndarray | None = None) -> np.ndarray:
    """The Jacobian at Z (default the neutral point) in an orthonormal basis of the subspace."""
    n_o = p.n_options
    zz = np.zeros((2, n_o)) if z is None else np.asarray(z, dtype=float)
    w = np.kron(np.eye(2), subspace_basis(n_o))  # (2 N_o) × 2 (N_o − 1)
    return w.T @ network_jacobian(zz, p) @ w


def _pattern(vector: np.ndarray, n_o: int) -> Pattern:
    """Agreement if the agents' parts of a subspace eigenvector point the same way."""
    q = subspace_basis(n_o)
    robot, human = q @ vector[: n_o - 1], q @ vector[n_o - 1 :]
    overlap = float(robot @ human)
    scale = float(np.linalg.norm(robot) * np.linalg.norm(human))
    if scale > 0 and overlap > 1e-9 * scale:
        return "agreement"
    if scale > 0 and overlap < -1e-9 * scale:
        return "disagreement"
    return "mixed"


def option_thresholds(p: OptionsParams) -> OptionThresholds:
    """Every mode of the neutral point's Jacobian and the agreement / disagreement points."""
    hom = homogeneous(p)
    r = hom.pair.robot
    # K = J(u = 1) − J(u = 0), exactly, since J is affine in u.
    at = [restricted_jacobian(replace(hom, pair=_with_u(hom.pair, u))) for u in (0.0, 1.0)]
    k = at[1] - at[0]
    values, vectors = np.linalg.eig(k)
    order = np.argsort(values.real)
    groups: list[tuple[float, list[Pattern]]] = []
    for idx in order:
        kappa = float(values[idx].real)
        pattern = _pattern(vectors[:, idx].real, hom.n_options)
        if groups and abs(kappa - groups[-1][0]) <= _TOL * max(1.0, abs(kappa)):
            groups[-1][1].append(pattern)
        else:
            groups.append((kappa, [pattern]))
    slope = r.gamma - hom.delta
    modes = []
    for kappa, patterns in groups:
        kind: Pattern = patterns[0] if len(set(patterns)) == 1 else "mixed"
        lam = (kappa - (r.alpha - hom.beta)) / slope if slope != 0 else None
        modes.append(
            Mode(
                pattern=kind,
                kappa=kappa,
                adjacency_eigenvalue=lam,
                multiplicity=len(patterns),
                u_star=r.d / kappa if kappa > 0 else None,
                jacobian_eigenvalue=-r.d + r.u * kappa,
            )
        )

    def first(kind: Pattern) -> float | None:
        points = [m.u_star for m in modes if m.pattern == kind and m.u_star is not None]
        return min(points) if points else None

    return OptionThresholds(
        n_options=hom.n_options,
        u=r.u,
        d=r.d,
        modes=tuple(modes),
        u_agreement=first("agreement"),
        u_disagreement=first("disagreement"),
    )


def _with_u(pair: PairParams, u: float) -> PairParams:
    r = replace(pair.robot, u=u)
    return PairParams(robot=r, human=r, a_rh=pair.a_rh, a_hr=pair.a_hr)
