"""Numerics over the vector field of eqs 1-2: stability tests, a contraction bound, 2-D Newton.

Shared by the bias sweep (Fig 3a) and the equilibrium finder (Fig 3b). The field and its
Jacobian (eq 3) are the model's (`services.model.dynamics.pair_rhs`, `jacobian_entries`); every
function here works element-wise on NumPy arrays of any broadcastable shape, so a whole grid of
bias pairs is handled in one call.
"""

from __future__ import annotations

import math

import numpy as np

from services.model.dynamics import ArrayLike, Jacobian, PairParams, jacobian_entries, pair_rhs

# max |d/dw sech²(w)| = 4 / (3√3), attained at tanh(w) = ±1/√3.
_MAX_SECH2_SLOPE = 4.0 / (3.0 * math.sqrt(3.0))


def is_stable(j: Jacobian) -> np.ndarray:
    """True where both eigenvalues of the 2×2 Jacobian have negative real part (tr < 0, det > 0)."""
    j11, j12, j21, j22 = j
    return np.asarray((j11 + j22 < 0.0) & (j11 * j22 - j12 * j21 > 0.0))


def log_norm(j: Jacobian) -> np.ndarray:
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
    b_r: ArrayLike,
    b_h: ArrayLike,
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
            f_r, f_h = pair_rhs(z_r, z_h, b_r, b_h, p)
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
    f_r, f_h = pair_rhs(z_r, z_h, b_r, b_h, p)
    return np.maximum(np.abs(f_r), np.abs(f_h))
