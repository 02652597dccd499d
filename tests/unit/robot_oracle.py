"""An independent reference of the N_o-option robot's RK4 (eq 1 over N_o options with eq 6).

`services.model.decision.rk4_robot` is the production form, on plain floats. This is the same
scheme on NumPy vectors, its rates taken from `services.model.dynamics.general_rates` (the
N_o-option formula alone, no two-option kernel, β and δ included) and its eq 6 written out
here: the tests hold the float form to it to 1e-12, and benchmarks/options_decision.py times
the float form against it. Not production code.
"""

from __future__ import annotations

import numpy as np

from services.model.bias import BiasParams
from services.model.dynamics import OptionsParams, general_rates, leading_option, option_vector


def numpy_rk4_robot(
    z_r: np.ndarray,
    s: float,
    z_hat: np.ndarray,
    steps: list[float],
    p: OptionsParams,
    option: int | None,
    bias: BiasParams | None = None,
) -> tuple[np.ndarray, float]:
    """(z_r, s) after RK4 `steps` (s) with ẑ_h held; `option` None: controller off, s frozen."""
    bp = bias if bias is not None else BiasParams()
    b_star = bp.threshold(p.pair.robot.u)
    robot, social = p.pair.robot, p.pair.a_rh * np.asarray(z_hat, dtype=float)
    direction = option_vector(option, p.n_options) if option is not None else None
    h = leading_option(z_hat)

    def rate(z: np.ndarray, b: np.ndarray) -> np.ndarray:
        return general_rates(z, social, b, robot, p.beta, p.delta)

    def s_rate(s_: float, z: np.ndarray) -> float:
        assert h is not None
        return -bp.sigma * float(z[h]) + bp.K * bp.sigma * max(0.0, b_star - abs(s_))

    z = np.array(z_r, dtype=float)
    z[-1] = -z[:-1].sum()
    for dt in steps:
        half = 0.5 * dt
        if direction is not None and h is not None and z[h] < np.max(z):
            k1z, k1b = rate(z, s * direction), s_rate(s, z)
            z2, s2 = z + half * k1z, s + half * k1b
            k2z, k2b = rate(z2, s2 * direction), s_rate(s2, z2)
            z3, s3 = z + half * k2z, s + half * k2b
            k3z, k3b = rate(z3, s3 * direction), s_rate(s3, z3)
            z4, s4 = z + dt * k3z, s + dt * k3b
            k4z, k4b = rate(z4, s4 * direction), s_rate(s4, z4)
            s = min(bp.b_max, max(-bp.b_max, s + (dt / 6.0) * (k1b + 2 * k2b + 2 * k3b + k4b)))
        else:
            b = s * direction if direction is not None else np.zeros_like(z)
            k1z = rate(z, b)
            k2z = rate(z + half * k1z, b)
            k3z = rate(z + half * k2z, b)
            k4z = rate(z + dt * k3z, b)
        z = z + (dt / 6.0) * (k1z + 2.0 * k2z + 2.0 * k3z + k4z)
        z[-1] = -z[:-1].sum()
    return z, s
