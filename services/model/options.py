"""N_o-option nonlinear opinion dynamics of the robot-human pair (docs/multi-option.md).

For agents i (0 = robot, 1 = human) and options j = 1…N_o, opinions z_ij with Σ_j z_ij = 0:

    ż_ij = F_ij(Z) − (1/N_o) Σ_l F_il(Z)
    F_ij = −d_i z_ij + u_i [ tanh(α_i z_ij + γ_i s_ij) + Σ_{l≠j} tanh(β z_il + δ s_il) ] + b_ij
    s_ij = Σ_k a_ik z_kj            (A = PairParams.adjacency(): the robot sees the human, a_rh)

the model of Bizyaeva, Franci & Leonard (IEEE TAC 2023) with tanh as both saturations. With
N_o = 2, β = δ = 0 and x_i = z_i1 = −z_i2 it is eq 1-2 with b_i = (b_i1 − b_i2)/2; option 0 is
red (z > 0 in the two-option convention), option 1 blue. β and δ (the weights of the other
options' opinions; not eq 6's β) are 0 by default, which keeps the paper's thresholds for any
N_o.

Arrays have options on the last axis and agents on the one before: Z is (..., 2, N_o), one
agent's opinion (..., N_o). Everything is pure NumPy and broadcasts over leading axes.

The zero-sum subspace is kept exactly: the integrator steps the first N_o − 1 options and sets
the last to minus their sum after every step (`on_subspace`), so Σ_j z_ij is zero by
construction rather than by rates that sum to zero up to rounding, which would drift.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from services.model.dynamics import AgentParams, PairParams

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
        for name in ("beta", "delta"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"OptionsParams.{name} must be finite, got {value!r}")

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
    d, u, alpha, gamma = p.columns()
    social = p.pair.adjacency() @ z
    return project(drive(z, social, b, d, u, alpha, gamma, p.beta, p.delta))


def robot_rate(z_r: np.ndarray, z_h: np.ndarray, b_r: np.ndarray, p: OptionsParams) -> np.ndarray:
    """ż_r (..., N_o) with the human's opinion z_h given (the observer's ẑ_h, held: ZOH)."""
    r = p.pair.robot
    social = p.pair.a_rh * z_h
    return project(drive(z_r, social, b_r, r.d, r.u, r.alpha, r.gamma, p.beta, p.delta))


def human_rate(z_h: np.ndarray, z_r: np.ndarray, b_h: np.ndarray, p: OptionsParams) -> np.ndarray:
    """ż_h (..., N_o) with the robot's opinion z_r given."""
    h = p.pair.human
    social = p.pair.a_hr * z_r
    return project(drive(z_h, social, b_h, h.d, h.u, h.alpha, h.gamma, p.beta, p.delta))


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


def jacobian(z: np.ndarray, p: OptionsParams) -> np.ndarray:
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
