"""Opinion dynamics (eqs 1-3): Jacobian, RK4 (the thresholds: test_thresholds.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.dynamics import (
    AgentParams,
    PairParams,
    human_rate,
    jacobian,
    pair_rhs,
    rk4_step,
    robot_rate,
)

finite = st.floats(min_value=-5.0, max_value=5.0, allow_nan=False)


def test_rk4_matches_linear_ode_solution():
    # ẏ = A y with a rotating, decaying A; exact solution via eigen-decomposition.
    A = np.array([[-0.5, 2.0], [-2.0, -0.5]])
    y0 = np.array([1.0, -0.3])
    dt, n = 0.01, 300
    y = y0.copy()
    for _ in range(n):
        y = rk4_step(lambda v: A @ v, y, dt)
    w, V = np.linalg.eig(A)
    exact = (V @ np.diag(np.exp(w * dt * n)) @ np.linalg.solve(V, y0)).real
    np.testing.assert_allclose(y, exact, atol=1e-8)


def test_rk4_is_fourth_order():
    lam, y0, T = -3.0, 1.0, 1.0
    errors = []
    for n in (20, 40):
        y = y0
        for _ in range(n):
            y = rk4_step(lambda v: lam * v, y, T / n)
        errors.append(abs(y - y0 * math.exp(lam * T)))
    # Halving the step divides the error by ~2^4.
    assert 12.0 < errors[0] / errors[1] < 20.0


def test_rates_broadcast_over_arrays():
    p = PairParams()
    z_r = np.linspace(-2, 2, 5)
    z_h = np.linspace(1, -1, 5)
    dz_r, dz_h = pair_rhs(z_r, z_h, 0.5, -0.5, p)
    for i in range(5):
        assert dz_r[i] == pytest.approx(robot_rate(float(z_r[i]), float(z_h[i]), 0.5, p))
        assert dz_h[i] == pytest.approx(human_rate(float(z_h[i]), float(z_r[i]), -0.5, p))


@settings(max_examples=200, deadline=None)
@given(
    z_r=finite,
    z_h=finite,
    u=st.floats(0.1, 4.0),
    alpha=st.floats(-1.0, 1.0),
    gamma=st.floats(-10.0, 10.0),
    a_rh=st.floats(0.0, 1.0),
)
def test_jacobian_matches_finite_differences(z_r, z_h, u, alpha, gamma, a_rh):
    agent = AgentParams(u=u, alpha=alpha, gamma=gamma)
    p = PairParams(robot=agent, human=AgentParams(u=u * 0.5, alpha=-alpha), a_rh=a_rh, a_hr=0.7)
    h = 1e-6

    def f(v):
        return np.array(pair_rhs(v[0], v[1], 0.3, -0.2, p), dtype=float)

    x = np.array([z_r, z_h])
    numeric = np.column_stack(
        [(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(2)],
    )
    np.testing.assert_allclose(jacobian(z_r, z_h, p), numeric, rtol=1e-5, atol=1e-5)


def test_agent_params_validation():
    with pytest.raises(ValueError, match="finite"):
        AgentParams(u=float("nan"))
    with pytest.raises(ValueError, match="decay"):
        AgentParams(d=0.0)
