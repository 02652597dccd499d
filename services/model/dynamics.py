"""Nonlinear opinion dynamics of the robot-human pair: eqs 1-3 (SPEC §1), over any N_o options.

    ż_r = −d_r z_r + u_r tanh(α_r z_r + γ_r a_rh z_h) + b_r        (eq 1)
    ż_h = −d_h z_h + u_h tanh(α_h z_h + γ_h a_hr z_r) + b_h        (eq 2)

Sign convention everywhere: z > 0 ⇔ red, z < 0 ⇔ blue. Everything here is pure and works on
scalars or NumPy arrays alike (broadcasting). `opinion_rate` is the only place the equations are
written: the live decision model (`services.model.decision`), the simulated participant, the
analysis sweeps and the equilibrium finder all call it. Their bifurcation points (Sec 4.3, and
over N_o options) are `services.model.thresholds`'.

**Over N_o options** (docs/multi-option.md). For agents i (0 = robot, 1 = human) and options
j = 1…N_o, opinions z_ij with Σ_j z_ij = 0:

    ż_ij = F_ij(Z) − (1/N_o) Σ_l F_il(Z)
    F_ij = −d_i z_ij + u_i [ tanh(α_i z_ij + γ_i s_ij) + Σ_{l≠j} tanh(β z_il + δ s_il) ] + b_ij
    s_ij = Σ_k a_ik z_kj            (A = PairParams.adjacency(): the robot sees the human, a_rh)

the model of Bizyaeva, Franci & Leonard (IEEE TAC 2023) with tanh as both saturations. **The
reduction to eq 1:** with N_o = 2, β = δ = 0 and x_i = z_i1 = −z_i2, F_i1 − (F_i1 + F_i2)/2 =
−d_i x_i + u_i tanh(α_i x_i + γ_i a x_k) + (b_i1 − b_i2)/2 (tanh is odd): eq 1-2 with b_i =
(b_i1 − b_i2)/2. So the two-option case is computed by eq 1 itself (`agent_rates`' kernel) and
the general form is checked against it (tests/unit/test_dynamics.py, 1e-12). Option 0
is red (z > 0 in the two-option convention), option 1 blue. β and δ (the weights of the other
options' opinions; not eq 6's β) are 0 by default, which keeps the paper's thresholds for any
N_o.

Arrays have options on the last axis and agents on the one before: Z is (..., 2, N_o), one
agent's opinion (..., N_o). The zero-sum subspace is kept exactly: the integrator steps the
first N_o − 1 options and sets the last to minus their sum after every step (`on_subspace`), so
Σ_j z_ij is zero by construction rather than by rates that sum to zero up to rounding.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any, TypeAlias, TypeVar, overload

import numpy as np

from services.model.checks import require_finite

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


# -- Over N_o options (the module doc) ----------------------------------------------------------

ROBOT, HUMAN = 0, 1  # agent rows of Z, the order of PairParams.adjacency()


@dataclass(frozen=True, slots=True)
class OptionsParams:
    """The pair's dynamics over `n_options` options: eq 1-2's parameters plus β and δ."""

    pair: PairParams = field(default_factory=PairParams)
    n_options: int = 3
    beta: float = 0.0  # weight of the agent's own opinion of the other options (Bizyaeva's β)
    delta: float = 0.0  # weight of the neighbours' opinions of the other options (δ)

    def __post_init__(self) -> None:
        if isinstance(self.n_options, bool) or not isinstance(self.n_options, int):
            raise ValueError(f"OptionsParams.n_options must be an int, got {self.n_options!r}")
        if self.n_options < 2:
            raise ValueError(f"OptionsParams.n_options must be >= 2, got {self.n_options}")
        require_finite(self, "beta", "delta")

    def agents(self) -> tuple[AgentParams, AgentParams]:
        """(robot, human): the rows of Z."""
        return self.pair.robot, self.pair.human

    def columns(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(d, u, α, γ) of both agents as (2, 1) columns, to broadcast against Z."""
        r, h = self.agents()
        return tuple(  # type: ignore[return-value]
            np.array([[getattr(r, k)], [getattr(h, k)]]) for k in ("d", "u", "alpha", "gamma")
        )


def option_vector(option: int, n_options: int) -> np.ndarray:
    """The zero-sum direction 2 (e_option − 1/N_o) of one option.

    N_o = 2 gives (1, −1) for option 0 (red) and (−1, 1) for option 1 (blue). With this scale
    the lead of `option` over every other one is 2 for any N_o, as x = ±1 gives in the
    two-option model: the observer's ẑ_h and the bias controller's b_r both use it.
    """
    if not 0 <= option < n_options:
        raise ValueError(f"option must be in 0..{n_options - 1}, got {option}")
    v = np.full(n_options, -2.0 / n_options)
    v[option] += 2.0
    return v


def on_subspace(z: np.ndarray) -> np.ndarray:
    """Z with its last option set to minus the sum of the others: Σ_j z_j = 0 by construction."""
    out = np.array(z, dtype=float, copy=True)
    out[..., -1] = -out[..., :-1].sum(axis=-1)
    return out


def leading_option(z: np.ndarray) -> int | None:
    """The option with the strictly largest opinion, or None on a tie for the largest (z = 0)."""
    flat = np.asarray(z, dtype=float)
    best = int(np.argmax(flat))
    top = flat[best]
    if np.count_nonzero(flat == top) > 1:
        return None
    return best


def drive(
    z: np.ndarray,
    social: np.ndarray,
    b: np.ndarray,
    d: np.ndarray | float,
    u: np.ndarray | float,
    alpha: np.ndarray | float,
    gamma: np.ndarray | float,
    beta: float,
    delta: float,
) -> np.ndarray:
    """F of the module doc for one or more agents; `social` is s = A Z (the neighbours' sum)."""
    same = np.tanh(alpha * z + gamma * social)
    if beta == 0.0 and delta == 0.0:
        # Σ_{l≠j} tanh(0) = 0: skipped, so the two-option case is eq 1's arithmetic exactly.
        return -d * z + u * same + b
    cross = np.tanh(beta * z + delta * social)
    others = cross.sum(axis=-1, keepdims=True) - cross  # Σ_{l≠j}
    return -d * z + u * (same + others) + b


def project(f: np.ndarray) -> np.ndarray:
    """The projection onto the zero-sum subspace: f minus its mean over options."""
    return f - f.mean(axis=-1, keepdims=True)


def network_rate(z: np.ndarray, b: np.ndarray, p: OptionsParams) -> np.ndarray:
    """Ż of the module doc for the pair Z (..., 2, N_o) with biases B (broadcastable to Z)."""
    z = np.asarray(z, dtype=float)
    social = p.pair.adjacency() @ z
    bb = np.broadcast_to(np.asarray(b, dtype=float), z.shape)
    return np.stack(
        [agent_rates(z[..., i, :], social[..., i, :], bb[..., i, :], agent, p.beta, p.delta)
         for i, agent in enumerate(p.agents())],
        axis=-2,
    )


def agent_rates(
    z: np.ndarray, social: np.ndarray, b: np.ndarray | float, agent: AgentParams,
    beta: float = 0.0, delta: float = 0.0,
) -> np.ndarray:
    """One agent's ż (..., N_o): its F projected on the zero-sum subspace.

    The paper's two options (N_o = 2, β = δ = 0, z and s on the subspace) are computed by eq 1
    itself (`opinion_rate`, the two-option kernel) on x = z_0 with b = (b_0 − b_1)/2, and
    returned as (ẋ, −ẋ): the paper's arithmetic, chosen here for any caller. `general_rates` is
    the form for any N_o; the two agree to rounding at N_o = 2 (tests/unit/test_dynamics.py).
    """
    z, social = np.asarray(z, dtype=float), np.asarray(social, dtype=float)
    if (z.shape[-1] == 2 and beta == 0.0 and delta == 0.0
            and np.array_equal(z[..., 1], -z[..., 0])
            and np.array_equal(social[..., 1], -social[..., 0])):
        # On the subspace (z = (x, −x), as every integrator keeps it); off it (a finite
        # difference of the Jacobian) only the general form is the model.
        bb = np.broadcast_to(np.asarray(b, dtype=float), z.shape)
        x_dot = opinion_rate(z[..., 0], social[..., 0],
                             0.5 * (bb[..., 0] - bb[..., 1]), agent.d, agent.u, agent.alpha,
                             agent.gamma)
        return np.stack([x_dot, -x_dot], axis=-1)
    return general_rates(z, social, b, agent, beta, delta)


def general_rates(
    z: np.ndarray, social: np.ndarray, b: np.ndarray | float, agent: AgentParams,
    beta: float = 0.0, delta: float = 0.0,
) -> np.ndarray:
    """`agent_rates` by the N_o-option formula alone (no two-option kernel): F minus its mean."""
    return project(drive(np.asarray(z, dtype=float), social, np.asarray(b, dtype=float),
                         agent.d, agent.u, agent.alpha, agent.gamma, beta, delta))


def robot_rates(z_r: np.ndarray, z_h: np.ndarray, b_r: np.ndarray, p: OptionsParams) -> np.ndarray:
    """ż_r (..., N_o) with the human's opinion z_h given (the observer's ẑ_h, held: ZOH)."""
    return agent_rates(z_r, p.pair.a_rh * np.asarray(z_h), b_r, p.pair.robot, p.beta, p.delta)


def human_rates(z_h: np.ndarray, z_r: np.ndarray, b_h: np.ndarray, p: OptionsParams) -> np.ndarray:
    """ż_h (..., N_o) with the robot's opinion z_r given."""
    return agent_rates(z_h, p.pair.a_hr * np.asarray(z_r), b_h, p.pair.human, p.beta, p.delta)


def rk4_network(
    z: np.ndarray, b: np.ndarray, p: OptionsParams, dt: float, steps: int
) -> np.ndarray:
    """`steps` classical RK4 steps of the pair with constant biases, kept on the subspace.

    Vectorised over leading axes: a whole grid of initial opinions or biases in one pass.
    """
    z = on_subspace(np.asarray(z, dtype=float))
    half, sixth = 0.5 * dt, dt / 6.0
    for _ in range(steps):
        k1 = network_rate(z, b, p)
        k2 = network_rate(z + half * k1, b, p)
        k3 = network_rate(z + half * k2, b, p)
        k4 = network_rate(z + dt * k3, b, p)
        z = on_subspace(z + sixth * (k1 + 2.0 * (k2 + k3) + k4))
    return z


def network_jacobian(z: np.ndarray, p: OptionsParams) -> np.ndarray:
    """∂Ż/∂Z of the pair at Z (2, N_o), as a (2 N_o × 2 N_o) matrix (row-major: agent, option).

    Biases do not enter: they shift F, not its derivative. The projection makes every column
    zero-sum, so the matrix maps the zero-sum subspace into itself.
    """
    z = np.asarray(z, dtype=float)
    n_a, n_o = z.shape
    d, u, alpha, gamma = p.columns()
    adj = p.pair.adjacency()
    social = adj @ z
    sech_same = 1.0 - np.tanh(alpha * z + gamma * social) ** 2  # (i, j)
    sech_cross = 1.0 - np.tanh(p.beta * z + p.delta * social) ** 2  # (i, l)
    eye_a, eye_o = np.eye(n_a), np.eye(n_o)
    self_or_social = alpha * eye_a + gamma * adj  # (i, m): ∂(α z_ij + γ s_ij)/∂z_mj
    cross_weight = p.beta * eye_a + p.delta * adj  # (i, m)
    # ∂F_ij/∂z_mn, indices (i, j, m, n)
    jac = -(d[:, :, None, None] * eye_a[:, None, :, None] * eye_o[None, :, None, :])
    same_option = eye_o[None, :, None, :]  # δ_jn
    other_option = 1.0 - same_option
    jac = jac + (u * sech_same)[:, :, None, None] * self_or_social[:, None, :, None] * same_option
    cross = u[:, :, None, None] * cross_weight[:, None, :, None] * sech_cross[:, None, None, :]
    jac = jac + cross * other_option
    jac = jac - jac.mean(axis=1, keepdims=True)  # the projection acts on j
    return jac.reshape(n_a * n_o, n_a * n_o)


def subspace_basis(n_options: int) -> np.ndarray:
    """An orthonormal basis Q (N_o × (N_o − 1)) of the zero-sum vectors (Helmert's)."""
    q = np.zeros((n_options, n_options - 1))
    for k in range(1, n_options):
        q[:k, k - 1] = 1.0
        q[k, k - 1] = -float(k)
        q[:, k - 1] /= math.sqrt(k * (k + 1))
    return q


def float_rates(
    z: list[float], social: list[float], b: list[float],
    d: float, u: float, alpha: float, gamma: float,
) -> list[float]:
    """One agent's ż over N_o options on plain floats, for β = δ = 0: F minus its mean.

    `general_rates`' arithmetic for one agent, without NumPy's per-call overhead on vectors
    of three (the decision engine's and the simulated person's camera-rate loops).

    `social` is the neighbour's opinion times the adjacency weight (a_rh ẑ_h, a_hr z_r).
    """
    tanh = math.tanh
    f = [-d * zj + u * tanh(alpha * zj + gamma * sj) + bj
         for zj, sj, bj in zip(z, social, b, strict=True)]
    mean = sum(f) / len(f)
    return [fj - mean for fj in f]
