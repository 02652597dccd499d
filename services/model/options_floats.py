"""`options_bias.advance_robot` on plain floats, for the decision engine's camera-rate loop.

The same equations and scheme (RK4 with ẑ_h held, the controller's freeze decided once per
step from its start, |s| clamped after it, the last option set to minus the sum of the others
after every step), written out on Python floats because NumPy's per-call overhead on vectors
of three dominates: 4-6× faster per 30 Hz pose (`benchmarks/options_decision.py`). Only for
β = δ = 0 (the paper's, and the default); `advance` falls
back to the NumPy form otherwise. A test checks the two agree to 1e-12.
"""

from __future__ import annotations

import numpy as np

from services.model.bias import BiasParams
from services.model.dynamics import OptionsParams, float_rates, leading_option, option_vector
from services.model.options_bias import advance_robot


def advance(
    z_r: np.ndarray,
    s: float,
    z_hat: np.ndarray,
    steps: list[float],
    p: OptionsParams,
    option: int | None,
    bias: BiasParams | None = None,
) -> tuple[np.ndarray, float]:
    """(z_r, s) after RK4 `steps` (s): `advance_robot`'s result, computed on floats."""
    if p.beta != 0.0 or p.delta != 0.0:
        return advance_robot(z_r, s, z_hat, steps, p, option, bias)
    bp = bias if bias is not None else BiasParams()
    r = p.pair.robot
    d, u, alpha, gamma = r.d, r.u, r.alpha, r.gamma
    b_star, sigma, gain, b_max = bp.threshold(r.u), bp.sigma, bp.K, bp.b_max
    n = p.n_options
    social = [p.pair.a_rh * float(x) for x in z_hat]
    v = [float(x) for x in option_vector(option, n)] if option is not None else None
    h = leading_option(z_hat)
    z = [float(x) for x in z_r]
    z[-1] = -sum(z[:-1])

    def biasrate(s_: float, z_: list[float]) -> float:
        assert h is not None
        return -sigma * z_[h] + gain * sigma * max(0.0, b_star - abs(s_))

    zero = [0.0] * n
    for dt in steps:
        half = 0.5 * dt
        running = v is not None and h is not None and z[h] < max(z)
        b = [s * vj for vj in v] if v is not None else zero
        k1 = float_rates(z, social, b, d, u, alpha, gamma)
        if running:
            assert v is not None
            k1b = biasrate(s, z)
            z2 = [zj + half * kj for zj, kj in zip(z, k1, strict=True)]
            s2 = s + half * k1b
            k2 = float_rates(z2, social, [s2 * vj for vj in v], d, u, alpha, gamma)
            k2b = biasrate(s2, z2)
            z3 = [zj + half * kj for zj, kj in zip(z, k2, strict=True)]
            s3 = s + half * k2b
            k3 = float_rates(z3, social, [s3 * vj for vj in v], d, u, alpha, gamma)
            k3b = biasrate(s3, z3)
            z4 = [zj + dt * kj for zj, kj in zip(z, k3, strict=True)]
            s4 = s + dt * k3b
            k4 = float_rates(z4, social, [s4 * vj for vj in v], d, u, alpha, gamma)
            k4b = biasrate(s4, z4)
            s = min(b_max, max(-b_max, s + (dt / 6.0) * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)))
        else:
            k2 = float_rates([zj + half * kj for zj, kj in zip(z, k1, strict=True)], social, b,
                       d, u, alpha, gamma)
            k3 = float_rates([zj + half * kj for zj, kj in zip(z, k2, strict=True)], social, b,
                       d, u, alpha, gamma)
            k4 = float_rates([zj + dt * kj for zj, kj in zip(z, k3, strict=True)], social, b,
                       d, u, alpha, gamma)
        z = [zj + (dt / 6.0) * (a + 2.0 * (bb + c) + e)
             for zj, a, bb, c, e in zip(z, k1, k2, k3, k4, strict=True)]
        z[-1] = -sum(z[:-1])
    return np.array(z), s
