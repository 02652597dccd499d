"""Vectorised vector field of eqs 1-2, its Jacobian (eq 3) and a 2-D Newton solver.

Shared by the bias sweep (Fig 3a) and the equilibrium finder (Fig 3b). Every function takes
NumPy arrays of any (common, broadcastable) shape and works element-wise, so a whole grid of
bias pairs is handled in one call. The Jacobian is the heterogeneous generalisation of eq 3:

    J = [[-d_r + u_r α_r s_r,      u_r γ_r a_rh s_r],
         [ u_h γ_h a_hr s_h,      -d_h + u_h α_h s_h]],   s_i = sech²(argument of agent i's tanh)

and is returned as its four entries (j11, j12, j21, j22) to keep the 2×2 algebra vectorised.
"""

from __future__ import annotations

import math
from typing import TypeAlias

import numpy as np

from services.model.dynamics import PairParams, pair_rhs

Jac: TypeAlias = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

# max |d/dw sech²(w)| = 4 / (3√3), attained at tanh(w) = ±1/√3.
_MAX_SECH2_SLOPE = 4.0 / (3.0 * math.sqrt(3.0))


def rates(
    z_r: np.ndarray, z_h: np.ndarray, b_r: np.ndarray, b_h: np.ndarray, p: PairParams
) -> tuple[np.ndarray, np.ndarray]:
    """(ż_r, ż_h) of eqs 1-2, element-wise (the same code as the live decision service)."""
    return pair_rhs(z_r, z_h, b_r, b_h, p)  # type: ignore[return-value]


def jacobian_entries(z_r: np.ndarray, z_h: np.ndarray, p: PairParams) -> Jac:
    """The entries (j11, j12, j21, j22) of the Jacobian (eq 3) at each (z_r, z_h)."""
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


def is_stable(j: Jac) -> np.ndarray:
    """True where both eigenvalues of the 2×2 Jacobian have negative real part (tr < 0, det > 0)."""
    j11, j12, j21, j22 = j
    return (j11 + j22 < 0.0) & (j11 * j22 - j12 * j21 > 0.0)


def log_norm(j: Jac) -> np.ndarray:
    """Logarithmic 2-norm μ₂(J) = largest eigenvalue of (J + Jᵀ)/2.

    μ₂ < 0 means the Euclidean distance to the equilibrium shrinks under the linearised flow.
    """
    j11, j12, j21, j22 = j
    off = 0.5 * (j12 + j21)
    return 0.5 * (j11 + j22) + np.sqrt((0.5 * (j11 - j22)) ** 2 + off * off)


def jacobian_lipschitz(p: PairParams) -> float:
    """A Lipschitz constant L of z ↦ J(z) in the spectral norm: ‖J(z) − J(z')‖₂ ≤ L ‖z − z'‖₂.

    Row i of J is u_i s_i v_i with v_i the agent's (self, other) gain vector, and
    |Δs_i| ≤ (4/3√3) ‖v_i‖ ‖Δz‖; the Frobenius norm bounds the spectral norm.
    """
    r, h = p.robot, p.human
    row_r = r.u * (r.alpha**2 + (r.gamma * p.a_rh) ** 2)
    row_h = h.u * (h.alpha**2 + (h.gamma * p.a_hr) ** 2)
    return _MAX_SECH2_SLOPE * math.hypot(row_r, row_h)


def newton(
    z_r: np.ndarray,
    z_h: np.ndarray,
    b_r: np.ndarray,
    b_h: np.ndarray,
    p: PairParams,
    iterations: int = 10,
    step_tol: float = 1e-15,
) -> tuple[np.ndarray, np.ndarray]:
    """Newton's method on ż_r = ż_h = 0 (eqs 4-5 scaled by u), element-wise from (z_r, z_h).

    Stops early once every step is below `step_tol`. Points whose Jacobian is singular end up
    non-finite; callers must check the residual and finiteness of the result.
    """
    z_r = np.array(z_r, dtype=float, copy=True)
    z_h = np.array(z_h, dtype=float, copy=True)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(iterations):
            f_r, f_h = rates(z_r, z_h, b_r, b_h, p)
            j11, j12, j21, j22 = jacobian_entries(z_r, z_h, p)
            det = j11 * j22 - j12 * j21
            d_r = (j22 * f_r - j12 * f_h) / det
            d_h = (j11 * f_h - j21 * f_r) / det
            z_r -= d_r
            z_h -= d_h
            step = np.maximum(np.abs(d_r), np.abs(d_h))
            if not np.any(step > step_tol * (1.0 + np.maximum(np.abs(z_r), np.abs(z_h)))):
                break
    return z_r, z_h


def max_rate(
    z_r: np.ndarray, z_h: np.ndarray, b_r: np.ndarray, b_h: np.ndarray, p: PairParams
) -> np.ndarray:
    """max(|ż_r|, |ż_h|): the residual used as the steady-state criterion."""
    f_r, f_h = rates(z_r, z_h, b_r, b_h, p)
    return np.maximum(np.abs(f_r), np.abs(f_h))
