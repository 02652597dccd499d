"""Bifurcation points of the robot-human pair at the neutral point, over any N_o options.

**The paper's two options (Sec 4.3).** At the origin the Jacobian of eqs 1-2 (eq 3) of the
homogeneous pair is −d I + u (α I + γ A): along the eigenvector of the adjacency A with
eigenvalue λ it grows past zero at u* = d / (α + γλ) when α + γλ > 0. `thresholds` reports this
for `nod analyze thresholds` (u*, u_d* at λ_min, the origin's eigenvalues, the regime).

**Over N_o options** (docs/multi-option.md, decision 5). At Z = 0 with no bias the Jacobian of
the N_o-option dynamics (`services.model.dynamics.network_jacobian`) restricted to the zero-sum
subspace is

    J(u) = −d I + u K,    K = (α − β) I + (γ − δ) A ⊗ I_{N_o−1}

(on zero-sum vectors Σ_{l≠j} z_l = −z_j, which turns β and δ into −β, −δ). It is affine in u,
so each eigenvalue κ of K with κ > 0 gives a bifurcation point u* = d / κ where −d + u κ crosses
zero; κ ≤ 0 gives none. The eigenvector says which kind: the robot's and the human's parts
point the same way (agreement: both lean to the same options) or opposite ways (disagreement).
With the paper's A (λ = ±1) and β = δ = 0 this is Sec 4.3's u* = d/(α + γλ) for every N_o, each
mode N_o − 1 times over.

`option_thresholds` computes the modes for any N_o. **Its two-option kernel**: with N_o = 2,
β = δ = 0 and a real, distinct adjacency spectrum (a_rh a_hr > 0, the paper's case) the modes
are Sec 4.3's arithmetic itself, κ = α + γλ per eigenvalue λ of A (the expression `thresholds`
uses), the pattern from A's eigenvector (a_rh, λ). Every other case is `general_modes`: the
eigen-decomposition of K computed numerically from `network_jacobian` (not from the formula
above, which the tests check it against). At N_o = 2 the kernel and the general computation
agree to 1e-12 (tests/unit/test_thresholds.py). Both analyses are the homogeneous pair's, as
Sec 4.3's: every agent takes the robot's (d, u, α, γ).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from services.model.dynamics import (
    AgentParams,
    OptionsParams,
    PairParams,
    jacobian,
    network_jacobian,
    subspace_basis,
)

Pattern = Literal["agreement", "disagreement", "mixed"]
_TOL = 1e-9  # eigenvalues closer than this (relative) are one mode counted with multiplicity


def adjacency_spectrum(p: PairParams) -> list[float]:
    """The eigenvalues λ of A (their real parts), ascending: (−√(a_rh a_hr), √(a_rh a_hr))."""
    return sorted(float(v) for v in np.linalg.eigvals(p.adjacency()).real)


def u_star_of(agent: AgentParams, lam: float) -> float | None:
    """Sec 4.3's u* = d / (α + γλ) along the adjacency eigenvalue λ; None when α + γλ ≤ 0."""
    kappa = agent.alpha + agent.gamma * lam
    return agent.d / kappa if kappa > 0 else None


# -- The paper's two options (Sec 4.3) ------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Thresholds:
    """Bifurcation thresholds of the homogeneous pair at the origin (Sec 4.3)."""

    u: float  # the attention parameter in use
    adjacency_eigenvalues: tuple[float, ...]
    u_star: tuple[float | None, ...]  # u* = d / (α + γλ) per eigenvalue; None where ≤ 0 or ∞
    u_d_star: float  # dissensus threshold, u* at λ_min
    origin_jacobian_eigenvalues: tuple[float, ...]
    dissensus_regime: bool  # u > u_d* and γ < 0: unbiased pair settles in dissensus


def thresholds(p: PairParams) -> Thresholds:
    """Compute u* for every adjacency eigenvalue and the dissensus threshold u_d* (Sec 4.3).

    Uses the robot's (d, α, γ, u): the analysis of the paper assumes a homogeneous pair.
    """
    a = p.robot
    lam = adjacency_spectrum(p)
    u_d = u_star_of(a, lam[0])
    if u_d is None:
        raise ValueError("no dissensus threshold: α + γ·λ_min ≤ 0 (choose γ < 0 and a_rh·a_hr > 0)")
    eig_origin = np.linalg.eigvals(jacobian(0.0, 0.0, p)).real
    return Thresholds(
        u=a.u,
        adjacency_eigenvalues=tuple(lam),
        u_star=tuple(u_star_of(a, v) for v in lam),
        u_d_star=u_d,
        origin_jacobian_eigenvalues=tuple(sorted(float(v) for v in eig_origin)),
        dissensus_regime=bool(a.u > u_d and a.gamma < 0),
    )


# -- Any N_o options -----------------------------------------------------------------------------


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


def option_thresholds(p: OptionsParams) -> OptionThresholds:
    """Every mode of the neutral point's Jacobian and the agreement / disagreement points.

    The paper's two options take the two-option kernel (Sec 4.3's κ = α + γλ, the module doc);
    everything else `general_modes`.
    """
    hom = homogeneous(p)
    pair = hom.pair
    kernel = (hom.n_options == 2 and hom.beta == 0.0 and hom.delta == 0.0
              and pair.a_rh * pair.a_hr > 0)
    return _assemble(hom, two_option_modes(hom) if kernel else general_modes(hom))


def general_thresholds(p: OptionsParams) -> OptionThresholds:
    """`option_thresholds` by the N_o-option computation alone (no two-option kernel)."""
    hom = homogeneous(p)
    return _assemble(hom, general_modes(hom))


def two_option_modes(hom: OptionsParams) -> list[tuple[float, Pattern]]:
    """The kernel: (κ, pattern) per adjacency eigenvalue λ, κ = α + γλ (Sec 4.3), ascending in κ.

    A's eigenvector for λ is (a_rh, λ): the agents' parts point the same way when a_rh λ > 0.
    Only for N_o = 2, β = δ = 0 and a_rh a_hr > 0 (λ real and distinct).
    """
    r, a_rh = hom.pair.robot, hom.pair.a_rh
    modes: list[tuple[float, Pattern]] = [
        (r.alpha + r.gamma * lam, "agreement" if a_rh * lam > 0 else "disagreement")
        for lam in adjacency_spectrum(hom.pair)
    ]
    return sorted(modes, key=lambda m: m[0])


def general_modes(hom: OptionsParams) -> list[tuple[float, Pattern]]:
    """(κ, pattern) per eigenvalue of K on the subspace, numerically, ascending in κ."""
    # K = J(u = 1) − J(u = 0), exactly, since J is affine in u.
    at = [restricted_jacobian(replace(hom, pair=_with_u(hom.pair, u))) for u in (0.0, 1.0)]
    values, vectors = np.linalg.eig(at[1] - at[0])
    return [(float(values[idx].real), _pattern(vectors[:, idx].real, hom.n_options))
            for idx in np.argsort(values.real)]


def _assemble(hom: OptionsParams, eigen: list[tuple[float, Pattern]]) -> OptionThresholds:
    """Group equal κ into modes (with multiplicity) and read off the bifurcation points."""
    r = hom.pair.robot
    groups: list[tuple[float, list[Pattern]]] = []
    for kappa, pattern in eigen:
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


def _with_u(pair: PairParams, u: float) -> PairParams:
    r = replace(pair.robot, u=u)
    return PairParams(robot=r, human=r, a_rh=pair.a_rh, a_hr=pair.a_hr)
