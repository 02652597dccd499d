"""Two-agent, two-option nonlinear opinion dynamics (paper eqs 1-3, SPEC §1).

    ż_r = −d_r z_r + u_r tanh(α_r z_r + γ_r a_rh z_h) + b_r        (eq 1)
    ż_h = −d_h z_h + u_h tanh(α_h z_h + γ_h a_hr z_r) + b_h        (eq 2)

Sign convention everywhere: z > 0 ⇔ red, z < 0 ⇔ blue. Everything here is pure and works on
scalars or NumPy arrays alike (broadcasting). `opinion_rate` is the only place the equations are
written: the live decision model (`services.model.decision`), the simulated participant, the
analysis sweeps and the equilibrium finder all call it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any, TypeAlias, TypeVar, overload

import numpy as np

ArrayLike: TypeAlias = float | np.ndarray
Y = TypeVar("Y", float, np.ndarray)  # a state: a float stays a float, an array an array


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


@overload
def opinion_rate(
    z: float,
    z_other: float,
    b: float,
    d: float,
    u: float,
    alpha: float,
    gamma_a: float,
    tanh: Callable[[Any], Any] = ...,
) -> float: ...
@overload
def opinion_rate(
    z: np.ndarray,
    z_other: ArrayLike,
    b: ArrayLike,
    d: float,
    u: float,
    alpha: float,
    gamma_a: float,
    tanh: Callable[[Any], Any] = ...,
) -> np.ndarray: ...
@overload
def opinion_rate(
    z: ArrayLike,
    z_other: ArrayLike,
    b: ArrayLike,
    d: float,
    u: float,
    alpha: float,
    gamma_a: float,
    tanh: Callable[[Any], Any] = ...,
) -> ArrayLike: ...
def opinion_rate(
    z: ArrayLike,
    z_other: ArrayLike,
    b: ArrayLike,
    d: float,
    u: float,
    alpha: float,
    gamma_a: float,
    tanh: Callable[[Any], Any] = np.tanh,
) -> ArrayLike:
    """ż = −d z + u tanh(α z + γ a z_other) + b: eq 1 for the robot, eq 2 for the human.

    The one place the opinion dynamics are written. `gamma_a` is γ times the adjacency weight
    (γ_r a_rh for eq 1). `tanh` is np.tanh for arrays (the analysis) and may be math.tanh for
    plain floats (the live decision model and the simulated participant: 20× faster per call).
    """
    return -d * z + u * tanh(alpha * z + gamma_a * z_other) + b


def robot_rate(z_r: ArrayLike, z_h: ArrayLike, b_r: ArrayLike, p: PairParams) -> ArrayLike:
    """ż_r of eq 1."""
    r = p.robot
    return opinion_rate(z_r, z_h, b_r, r.d, r.u, r.alpha, r.gamma * p.a_rh)


def human_rate(z_h: ArrayLike, z_r: ArrayLike, b_h: ArrayLike, p: PairParams) -> ArrayLike:
    """ż_h of eq 2."""
    h = p.human
    return opinion_rate(z_h, z_r, b_h, h.d, h.u, h.alpha, h.gamma * p.a_hr)


@overload
def pair_rhs(
    z_r: float, z_h: float, b_r: float, b_h: float, p: PairParams
) -> tuple[float, float]: ...
@overload
def pair_rhs(
    z_r: np.ndarray, z_h: np.ndarray, b_r: ArrayLike, b_h: ArrayLike, p: PairParams
) -> tuple[np.ndarray, np.ndarray]: ...
@overload
def pair_rhs(
    z_r: ArrayLike, z_h: ArrayLike, b_r: ArrayLike, b_h: ArrayLike, p: PairParams
) -> tuple[ArrayLike, ArrayLike]: ...
def pair_rhs(
    z_r: ArrayLike, z_h: ArrayLike, b_r: ArrayLike, b_h: ArrayLike, p: PairParams
) -> tuple[ArrayLike, ArrayLike]:
    """Right-hand side of the coupled system (eqs 1-2)."""
    return robot_rate(z_r, z_h, b_r, p), human_rate(z_h, z_r, b_h, p)


def rk4_step(f: Callable[[Y], Y], y: Y, dt: float) -> Y:
    """One classical Runge-Kutta step of ẏ = f(y) (autonomous; inputs held constant = ZOH)."""
    k1 = f(y)
    k2 = f(y + 0.5 * dt * k1)
    k3 = f(y + 0.5 * dt * k2)
    k4 = f(y + dt * k3)
    return y + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def rk4_pair(
    z_r: np.ndarray,
    z_h: np.ndarray,
    b_r: ArrayLike,
    b_h: ArrayLike,
    p: PairParams,
    dt: float,
    steps: int,
) -> tuple[np.ndarray, np.ndarray]:
    """`steps` classical RK4 steps of eqs 1-2 with constant biases, element-wise over arrays.

    The two components are stepped side by side (no stacking), which keeps a whole grid of
    bias pairs in one vectorised pass (the bias sweep, Fig 3a).
    """
    half = 0.5 * dt
    sixth = dt / 6.0
    for _ in range(steps):
        k1r, k1h = pair_rhs(z_r, z_h, b_r, b_h, p)
        k2r, k2h = pair_rhs(z_r + half * k1r, z_h + half * k1h, b_r, b_h, p)
        k3r, k3h = pair_rhs(z_r + half * k2r, z_h + half * k2h, b_r, b_h, p)
        k4r, k4h = pair_rhs(z_r + dt * k3r, z_h + dt * k3h, b_r, b_h, p)
        z_r = z_r + sixth * (k1r + 2.0 * (k2r + k3r) + k4r)
        z_h = z_h + sixth * (k1h + 2.0 * (k2h + k3h) + k4h)
    return z_r, z_h


Jacobian: TypeAlias = tuple[ArrayLike, ArrayLike, ArrayLike, ArrayLike]


def jacobian_entries(z_r: ArrayLike, z_h: ArrayLike, p: PairParams) -> Jacobian:
    """The entries (j11, j12, j21, j22) of the Jacobian of eqs 1-2 (eq 3) at each (z_r, z_h).

    The heterogeneous generalisation of eq 3, element-wise over arrays:

        J = [[-d_r + u_r α_r s_r,      u_r γ_r a_rh s_r],
             [ u_h γ_h a_hr s_h,      -d_h + u_h α_h s_h]],   s_i = sech²(agent i's tanh argument)
    """
    r, h = p.robot, p.human
    t_r = np.tanh(r.alpha * z_r + r.gamma * p.a_rh * z_h)
    t_h = np.tanh(h.alpha * z_h + h.gamma * p.a_hr * z_r)
    q_r = r.u * (1.0 - t_r * t_r)  # u_r sech²(·)
    q_h = h.u * (1.0 - t_h * t_h)
    return (
        -r.d + r.alpha * q_r,
        r.gamma * p.a_rh * q_r,
        h.gamma * p.a_hr * q_h,
        -h.d + h.alpha * q_h,
    )


def jacobian(z_r: float, z_h: float, p: PairParams) -> np.ndarray:
    """The Jacobian (eq 3) at one point, as a 2×2 matrix."""
    j11, j12, j21, j22 = jacobian_entries(z_r, z_h, p)
    return np.array([[j11, j12], [j21, j22]], dtype=float)


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
