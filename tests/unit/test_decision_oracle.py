"""The live decision model against eqs 1 and 6 written out here, independently of the model code.

These tests are the oracle for the running code path (`DecisionModel.on_hand` →
`opinion_rate`, `bias_rate`): a change of eq 1, eq 6, the freeze or the clamp in the model
makes them fail, because nothing here calls the model's equations.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from services.model.decision import DecisionModel

NS = 1_000_000_000
D, U, ALPHA, GAMMA = 10.0, 2.24, 0.05, -8.0  # SPEC §1
SIGMA, K, B_STAR, B_MAX = 0.1, 16.0, 2.24 + 2.3, 6.0  # SPEC §3 with the derived margin


def eq1(z_r: float, z_hat: float, b_r: float) -> float:
    return -D * z_r + U * math.tanh(ALPHA * z_r + GAMMA * z_hat) + b_r


def eq6(b_r: float, z_r: float, z_hat: float, option: str) -> float:
    sigma = -SIGMA if option == "red" else SIGMA
    beta = -K * sigma
    return sigma * z_r * math.copysign(1.0, z_hat) + beta * max(0.0, B_STAR - abs(b_r))


def recorded_stream(hz: float, seconds: float, seed: int) -> list[tuple[int, list]]:
    """A hand that starts off-centre, hesitates, then reaches for the red box, with jitter."""
    rng = np.random.default_rng(seed)
    out = []
    x, y = 0.62, 0.86
    for i in range(int(hz * seconds)):
        t = i / hz
        if 0.3 < t < 0.6 or t > 1.2:  # reach up-right, pause, reach again
            x, y = x + 0.25 / hz, y - 0.35 / hz
        pts = [(x + rng.normal(0, 0.003), y + rng.normal(0, 0.003)) for _ in range(21)]
        out.append((round(t * NS), pts))
    return out


@pytest.mark.parametrize("hz", [30.0, 60.0])
def test_dissensus_trial_matches_eq1_to_1e6(hz):
    # b_r ≡ 0: z_r must follow eq 1 with ẑ_h held between poses (zero-order hold), as an
    # adaptive high-accuracy solver integrates it interval by interval.
    model = DecisionModel()
    model.reset("dissensus", None)
    stream = recorded_stream(hz, 2.0, seed=3)
    z_ref, held, t_prev = 0.0, 0.0, None
    worst = 0.0
    for t_ns, pts in stream:
        out = model.on_hand(t_ns, pts)
        if t_prev is not None:
            span = (t_ns - t_prev) / NS
            sol = solve_ivp(
                lambda _t, z, zh=held: [eq1(z[0], zh, 0.0)],
                (0.0, span),
                [z_ref],
                method="DOP853",
                rtol=1e-12,
                atol=1e-14,
            )
            z_ref = float(sol.y[0, -1])
        held, t_prev = out.z_hat, t_ns
        worst = max(worst, abs(out.z_r - z_ref))
        assert out.b_r == 0.0
    assert worst < 1e-6
    assert any(abs(v) > 0.1 for v in (model.z_r, z_ref))  # the stream did move the robot


@pytest.mark.parametrize("option", ["red", "blue"])
def test_consensus_trial_matches_eq1_and_eq6(option):
    # Reference: classical RK4 over the same 1 ms steps, with eq 6's freeze decided at each
    # step's start (the model's documented discretisation) and |b_r| clamped to b_max.
    model = DecisionModel()
    model.reset("consensus", option)
    stream = recorded_stream(30.0, 3.0, seed=8)
    z, b, held, t_prev = 0.0, 0.0, 0.0, None
    froze = moved = False
    for t_ns, pts in stream:
        out = model.on_hand(t_ns, pts)
        if t_prev is not None:
            n_full, rest = divmod(t_ns - t_prev, 1_000_000)
            for h in [1e-3] * n_full + ([rest * 1e-9] if rest else []):
                active = z * held < 0

                def f(
                    zz: float, bb: float, active: bool = active, zh: float = held
                ) -> tuple[float, float]:
                    return eq1(zz, zh, bb), eq6(bb, zz, zh, option) if active else 0.0

                k1 = f(z, b)
                k2 = f(z + h / 2 * k1[0], b + h / 2 * k1[1])
                k3 = f(z + h / 2 * k2[0], b + h / 2 * k2[1])
                k4 = f(z + h * k3[0], b + h * k3[1])
                z += h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
                b += h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
                b = max(-B_MAX, min(B_MAX, b))
                froze |= not active
                moved |= active
        held, t_prev = out.z_hat, t_ns
        assert out.z_r == pytest.approx(z, abs=1e-9)
        assert out.b_r == pytest.approx(b, abs=1e-9)
    assert froze and moved  # both branches of eq 6 ran
    sign = 1 if option == "red" else -1
    assert sign * model.b_r > 0  # the bias was pushed toward O
