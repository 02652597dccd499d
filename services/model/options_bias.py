"""The robot's bias controller over N_o options: eq 6 steering toward O (docs/multi-option.md).

The bias is a magnitude s along O's direction, b_r = s · option_vector(O) (so its lead for O
over every other option is 2 s, as b_r = ±s gives in the two-option model), and

    ṡ = −|σ| · z_r[h] + K |σ| · max(0, b* − |s|)      while the pair disagrees
    ṡ = 0                                              otherwise (s frozen)

where h is the human's leading option (the argmax of ẑ_h) and "disagrees" means the robot's
opinion of h is below its largest one. With N_o = 2, z_r[h] = z_r · sgn(ẑ_h) and the
condition is z_r · ẑ_h < 0: this is eq 6 with SPEC §3's signs, s = b_r · sgn(O). The defaults
are eq 6's (`services.model.bias.BiasParams`: |σ| = 0.1, K = 16, b* = u_r + margin, |s| ≤
b_max); with β = δ = 0 the bias must still beat u_r (the lead of tanh's saturation is 2 u_r,
against the bias's 2 s) for any N_o.

The robot's state (z_r, s) is stepped by RK4 with ẑ_h held, the freeze decided once per step
from the state at its start, |s| clamped after each step: `services.model.decision`'s scheme.
"""

from __future__ import annotations

import numpy as np

from services.model.bias import BiasParams
from services.model.dynamics import (
    OptionsParams,
    leading_option,
    on_subspace,
    option_vector,
    robot_rates,
)


def disagrees(z_r: np.ndarray, z_hat: np.ndarray) -> bool:
    """Whether the controller runs: the human leads with h and the robot's z_r[h] is not its max.

    The N_o-option reading of Algorithm 1's z_r · ẑ_h < 0: no leading option for the human
    (ẑ_h = 0 before any movement) or a robot already at its largest on h means no dissensus.
    """
    h = leading_option(z_hat)
    return h is not None and bool(z_r[h] < np.max(z_r))


def bias_rate(s: float, z_r: np.ndarray, h: int, sigma: float, K: float, b_star: float) -> float:
    """ṡ while the controller runs, with the magnitudes |σ| and K of eq 6 (see module doc)."""
    return -sigma * float(z_r[h]) + K * sigma * max(0.0, b_star - abs(s))


def split_span(span_ns: int, dt_ns: int) -> list[float]:
    """The RK4 steps (s) that cover span_ns: whole steps of dt_ns, then the rest (as decision)."""
    n_full, rest_ns = divmod(span_ns, dt_ns)
    steps = [dt_ns * 1e-9] * n_full
    if rest_ns:
        steps.append(rest_ns * 1e-9)
    return steps


def advance_robot(
    z_r: np.ndarray,
    s: float,
    z_hat: np.ndarray,
    steps: list[float],
    p: OptionsParams,
    option: int | None,
    bias: BiasParams | None = None,
) -> tuple[np.ndarray, float]:
    """(z_r, s) after RK4 `steps` (s) with ẑ_h held; `option` None: controller off, s frozen.

    `z_r` and `z_hat` are N_o-vectors (zero-sum); returns the new z_r (on the subspace) and s.
    """
    bp = bias if bias is not None else BiasParams()
    b_star = bp.threshold(p.pair.robot.u)
    sigma, gain, b_max = bp.sigma, bp.K, bp.b_max
    direction = option_vector(option, p.n_options) if option is not None else None
    h = leading_option(z_hat)
    z = on_subspace(z_r)
    for dt in steps:
        half = 0.5 * dt
        if direction is not None and h is not None and disagrees(z, z_hat):
            k1z = robot_rates(z, z_hat, s * direction, p)
            k1b = bias_rate(s, z, h, sigma, gain, b_star)
            z2, s2 = z + half * k1z, s + half * k1b
            k2z = robot_rates(z2, z_hat, s2 * direction, p)
            k2b = bias_rate(s2, z2, h, sigma, gain, b_star)
            z3, s3 = z + half * k2z, s + half * k2b
            k3z = robot_rates(z3, z_hat, s3 * direction, p)
            k3b = bias_rate(s3, z3, h, sigma, gain, b_star)
            z4, s4 = z + dt * k3z, s + dt * k3b
            k4z = robot_rates(z4, z_hat, s4 * direction, p)
            k4b = bias_rate(s4, z4, h, sigma, gain, b_star)
            s = min(b_max, max(-b_max, s + (dt / 6.0) * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)))
            # s entered the stages above at its value before the clamp, as b_r does in decision
        else:
            b = s * direction if direction is not None else 0.0 * z
            k1z = robot_rates(z, z_hat, b, p)
            k2z = robot_rates(z + half * k1z, z_hat, b, p)
            k3z = robot_rates(z + half * k2z, z_hat, b, p)
            k4z = robot_rates(z + dt * k3z, z_hat, b, p)
        z = on_subspace(z + (dt / 6.0) * (k1z + 2.0 * k2z + 2.0 * k3z + k4z))
    return z, s
