"""Robot bias controller (paper eq 6, Algorithm 1 "Bias Consensus", SPEC §3).

    ḃ_r = σ · z_r · sgn(ẑ_h) + β · max(0, b* − |b_r|)     while z_r · ẑ_h < 0    (eq 6)
    ḃ_r = 0                                                otherwise (b_r frozen)

with σ = −|σ| for O = red, +|σ| for O = blue and β = −K σ. In dissensus z_r · sgn(ẑ_h) = −|z_r|,
so both terms push b_r toward O. |b_r| is clamped to b_max. In dissensus-mode trials the
controller is off and b_r ≡ 0 (the caller does not call it).

Deviation from the paper: eq 6 uses b* = u_r. When the human heads straight for O, ẑ_h is
large and tanh(α z_r + γ ẑ_h) saturates at −sgn(O), so ż_r ≈ −d_r z_r − u_r sgn(O) + b_r and
z_r relaxes to (b_r − u_r sgn(O)) / d_r. The β term stops exactly when |b_r| = u_r, i.e. when
that equilibrium reaches z_r = 0, and the σ term shrinks with z_r: (z_r, b_r) → (0⁻, u_r)
asymptotically and z_r never changes sign (numerically b_r = 2.23999999 after 20 s with
u_r = 2.24). So by default b* = u_r + b_star_margin, which drives b_r past u_r and lets z_r
cross to O's sign; the margin sets how fast.

The margin is derived, not tuned (`services.analysis.bstar`, `nod analyze bstar`): the
requirement is that when the participant heads straight for O, the robot's arm is on O's side
(nearer O's box) when the participant presses, so Algorithm 2's "press the nearest buzzer" ends
in consensus. Run with the parts that run on the rig — the default observer on a 2 px-jittered
minimum-jerk reach, this model, Algorithm 2, the simulated arm — the smallest margin (0.1 grid)
that meets it for a press 2.2 s after "go" (a 0.3 s reaction and a 1.9 s reach: the 10th
percentile of the simulated cohort's consensus presses), for both options and every seed, is
2.3. Faster presses need more (1.8 s: 3.7); slower ones less (2.6 s: 1.5; 3.0 s: 0.7).
`b_star_margin = 0` restores the paper's rule.

The freeze is decided once per integration step (see `services.model.decision`), |b_r| is
clamped to b_max after each step, and b_r ≡ 0 in dissensus-mode trials (the controller is off).

**Over N_o options** (docs/multi-option.md). The bias is a magnitude s along O's direction,
b_r = s · option_vector(O) (its lead for O over every other option is 2 s, as b_r = ±s gives
with two options), and

    ṡ = −|σ| · z_r[h] + K |σ| · max(0, b* − |s|)      while the pair disagrees
    ṡ = 0                                              otherwise (s frozen)

where h is the human's leading option (the argmax of ẑ_h) and "disagrees" means the robot's
opinion of h is below its largest one (`options_bias_active`, `options_bias_rate`). With
N_o = 2, z_r = (x, −x) and ẑ_h = (m, −m): z_r[h] = x · sgn(m), "disagrees" is x · m < 0, and
s = b_r · sgn(O), so ṡ = sgn(O) ḃ_r: eq 6 with SPEC §3's signs. The paper's two-option
functions above are that case's kernel, which the paper's decision model runs; a property test
holds the two to 1e-12 (tests/unit/test_bias.py). The parameters are the same `BiasParams`;
with β = δ = 0 the bias must still beat u_r (the lead of tanh's saturation is 2 u_r, against
the bias's 2 s) for any N_o.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from services.model.checks import require_finite
from services.model.geometry import Colour, colour_sign


@dataclass(frozen=True, slots=True)
class BiasParams:
    """Parameters of the bias controller (eq 6; |σ| = 0.1 and K = 16 give |β| = 1.6, Sec 4.6)."""

    sigma: float = 0.1  # |σ|, gain of the sign-alignment term (1/s); the sign comes from O
    K: float = 16.0  # β = −K σ, gain of the threshold-raising term (1/s)
    b_star: float | None = None  # bias threshold b*; None → u_r + b_star_margin (see module doc)
    b_star_margin: float = 2.3  # added to u_r when b_star is None (derived: see above); 0: paper
    b_max: float = 6.0  # clamp |b_r| ≤ b_max: in dissensus the σ term never stops on its own

    def __post_init__(self) -> None:
        require_finite(self, "sigma", "K", "b_star_margin", "b_max")
        if self.sigma < 0 or self.K < 0 or self.b_star_margin < 0:
            raise ValueError(
                "BiasParams.sigma, K and b_star_margin are magnitudes and must be >= 0, got "
                f"sigma={self.sigma}, K={self.K}, b_star_margin={self.b_star_margin}"
            )
        if self.b_max <= 0:
            raise ValueError(f"BiasParams.b_max must be > 0, got {self.b_max}")
        if self.b_star is not None and not (math.isfinite(self.b_star) and self.b_star > 0):
            raise ValueError(
                f"BiasParams.b_star must be a finite number > 0 or None, got {self.b_star!r}"
            )

    def threshold(self, u_r: float) -> float:
        """The bias threshold b* for a robot with attention u_r (b_star, or u_r + margin)."""
        return self.b_star if self.b_star is not None else u_r + self.b_star_margin


def sigma_for(option: Colour, params: BiasParams | None = None) -> float:
    """Signed σ of eq 6: −|σ| for O = red, +|σ| for O = blue (SPEC §3)."""
    p = params if params is not None else BiasParams()
    return -colour_sign(option) * p.sigma


def beta_for(option: Colour, params: BiasParams | None = None) -> float:
    """β = −K σ of eq 6: +K|σ| for O = red, −K|σ| for O = blue."""
    p = params if params is not None else BiasParams()
    return -p.K * sigma_for(option, p)


def bias_active(z_r: float, z_hat: float) -> bool:
    """Whether the controller runs: the pair is in dissensus, z_r · ẑ_h < 0 (Algorithm 1)."""
    return z_r * z_hat < 0


def bias_rate(
    b_r: float, z_r: float, z_hat: float, sigma: float, beta: float, b_star: float
) -> float:
    """ḃ_r of eq 6 while the controller runs (`bias_active`), with signed σ and β of O.

    The one place eq 6 is written; the decision model calls it at every RK4 stage of an active
    step and holds b_r (ḃ_r = 0) otherwise. Plain floats: it runs ~30 times per hand pose.
    """
    sgn = 1.0 if z_hat > 0 else -1.0
    return sigma * z_r * sgn + beta * max(0.0, b_star - abs(b_r))


def options_bias_active(z_r: Sequence[float], h: int | None) -> bool:
    """Whether the controller runs over N_o options (the reading of `bias_active`).

    It runs while the human leads with h and the robot's opinion of h is not its largest. No
    leading option for the human (h None: ẑ_h = 0 before any movement, or a tie) or a robot
    already at its largest on h means no dissensus. Plain floats or an array alike.
    """
    return h is not None and bool(z_r[h] < max(z_r))


def options_bias_rate(s: float, z_rh: float, sigma: float, K: float, b_star: float) -> float:
    """ṡ over N_o options while the controller runs (`options_bias_active`), z_rh = z_r[h].

    The magnitudes |σ| and K of `BiasParams`: the sign of O is in its direction, not in σ.
    The one place the N_o-option eq 6 is written; the decision engine's N_o-option RK4
    (`services.model.decision.rk4_robot`) calls it at every stage of an active step.
    """
    return -sigma * z_rh + K * sigma * max(0.0, b_star - abs(s))
