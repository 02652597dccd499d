"""Two-agent, two-option nonlinear opinion dynamics (paper eqs 1-3, SPEC §1).

    ż_r = −d_r z_r + u_r tanh(α_r z_r + γ_r a_rh z_h) + b_r        (eq 1)
    ż_h = −d_h z_h + u_h tanh(α_h z_h + γ_h a_hr z_r) + b_h        (eq 2)

Sign convention everywhere: z > 0 ⇔ red, z < 0 ⇔ blue. Everything here is pure and works on
scalars or NumPy arrays alike (broadcasting), so the same code drives the live decision service
and the vectorised analysis sweeps.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import TypeAlias

import numpy as np

ArrayLike: TypeAlias = float | np.ndarray


@dataclass(frozen=True, slots=True)
class AgentParams:
    """Parameters of one agent's opinion dynamics (paper Sec 4.6 defaults)."""

    d: float = 10.0  # decay (1/s); > 0
    u: float = 2.24  # social attention / influence gain; > 0
    alpha: float = 0.05  # self-reinforcement weight
    gamma: float = -8.0  # inter-agent gain; < 0 promotes disagreement

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not math.isfinite(value):
                raise ValueError(f"AgentParams.{name} must be finite, got {value!r}")
        if self.d <= 0:
            raise ValueError(f"AgentParams.d (decay) must be > 0, got {self.d}")
        if self.u < 0:
            raise ValueError(f"AgentParams.u (attention) must be >= 0, got {self.u}")


@dataclass(frozen=True, slots=True)
class PairParams:
    """The robot-human pair: each agent's parameters and the adjacency weights."""

    robot: AgentParams = field(default_factory=AgentParams)
    human: AgentParams = field(default_factory=AgentParams)
    a_rh: float = 1.0  # robot observes human (1 = edge present)
    a_hr: float = 1.0  # human observes robot

    def adjacency(self) -> np.ndarray:
        """The adjacency matrix A = [[0, a_rh], [a_hr, 0]] of the two-agent network."""
        return np.array([[0.0, self.a_rh], [self.a_hr, 0.0]])


def robot_rate(z_r: ArrayLike, z_h: ArrayLike, b_r: ArrayLike, p: PairParams) -> ArrayLike:
    """ż_r of eq 1."""
    r = p.robot
    return -r.d * z_r + r.u * np.tanh(r.alpha * z_r + r.gamma * p.a_rh * z_h) + b_r


def human_rate(z_h: ArrayLike, z_r: ArrayLike, b_h: ArrayLike, p: PairParams) -> ArrayLike:
    """ż_h of eq 2."""
    h = p.human
    return -h.d * z_h + h.u * np.tanh(h.alpha * z_h + h.gamma * p.a_hr * z_r) + b_h


def rk4_step(f, y: ArrayLike, dt: float) -> ArrayLike:
    """One classical Runge-Kutta step of ẏ = f(y) (autonomous; inputs held constant = ZOH)."""
    k1 = f(y)
    k2 = f(y + 0.5 * dt * k1)
    k3 = f(y + 0.5 * dt * k2)
    k4 = f(y + dt * k3)
    return y + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def pair_rhs(
    z_r: ArrayLike, z_h: ArrayLike, b_r: ArrayLike, b_h: ArrayLike, p: PairParams
) -> tuple[ArrayLike, ArrayLike]:
    """Right-hand side of the coupled system (eqs 1-2)."""
    return robot_rate(z_r, z_h, b_r, p), human_rate(z_h, z_r, b_h, p)


def jacobian(z_r: float, z_h: float, p: PairParams) -> np.ndarray:
    """Jacobian of eqs 1-2 at (z_r, z_h) (eq 3, generalised to heterogeneous agents)."""
    r, h = p.robot, p.human
    s_r = 1.0 / math.cosh(r.alpha * z_r + r.gamma * p.a_rh * z_h) ** 2
    s_h = 1.0 / math.cosh(h.alpha * z_h + h.gamma * p.a_hr * z_r) ** 2
    return np.array(
        [
            [-r.d + r.u * r.alpha * s_r, r.u * r.gamma * p.a_rh * s_r],
            [h.u * h.gamma * p.a_hr * s_h, -h.d + h.u * h.alpha * s_h],
        ]
    )


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
    lam = sorted(float(v) for v in np.linalg.eigvals(p.adjacency()).real)

    def u_star_of(lmb: float) -> float | None:
        denom = a.alpha + a.gamma * lmb
        return a.d / denom if denom > 0 else None

    u_d = u_star_of(lam[0])
    if u_d is None:
        raise ValueError("no dissensus threshold: α + γ·λ_min ≤ 0 (choose γ < 0 and a_rh·a_hr > 0)")
    eig_origin = np.linalg.eigvals(jacobian(0.0, 0.0, p)).real
    return Thresholds(
        u=a.u,
        adjacency_eigenvalues=tuple(lam),
        u_star=tuple(u_star_of(v) for v in lam),
        u_d_star=u_d,
        origin_jacobian_eigenvalues=tuple(sorted(float(v) for v in eig_origin)),
        dissensus_regime=bool(a.u > u_d and a.gamma < 0),
    )
