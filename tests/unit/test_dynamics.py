"""Opinion dynamics (eqs 1-3): Jacobian, RK4 (the thresholds: test_thresholds.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.dynamics import (
    AgentParams,
    OptionsParams,
    PairParams,
    agent_rates,
    general_rates,
    human_rate,
    jacobian,
    network_jacobian,
    network_rate,
    on_subspace,
    option_vector,
    pair_rhs,
    rk4_network,
    rk4_pair,
    rk4_step,
    robot_rate,
    subspace_basis,
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


# --- over N_o options: the reduction to eq 1-2, the subspace, the options' symmetry, the Jacobian

value = st.floats(min_value=-4.0, max_value=4.0, allow_nan=False)
weight = st.floats(min_value=-3.0, max_value=3.0, allow_nan=False)
n_options = st.integers(min_value=2, max_value=6)


def pair_vector(x: float) -> np.ndarray:
    """The two-option opinion x as (z_red, z_blue) = (x, −x)."""
    return np.array([x, -x])


@settings(max_examples=60, deadline=None)
@given(value, value, value, value)
def test_two_option_rates_are_eq_1_and_2(z_r: float, z_h: float, b_r: float, b_h: float) -> None:
    pair = PairParams(robot=AgentParams(u=3.1, alpha=0.4), human=AgentParams(gamma=-2.0))
    p = OptionsParams(pair=pair, n_options=2)
    z = np.array([pair_vector(z_r), pair_vector(z_h)])
    b = np.array([pair_vector(b_r), pair_vector(b_h)])
    rate = network_rate(z, b, p)
    want_r, want_h = pair_rhs(z_r, z_h, b_r, b_h, pair)
    np.testing.assert_allclose(rate[:, 0], [want_r, want_h], rtol=0, atol=1e-12)
    np.testing.assert_allclose(rate[:, 1], -rate[:, 0], rtol=0, atol=1e-12)


def test_two_option_network_integrates_like_rk4_pair() -> None:
    p = OptionsParams(n_options=2)
    b_r, b_h = np.linspace(-5, 5, 7), np.linspace(4, -3, 7)
    z0 = np.zeros((7, 2, 2))
    z0[:, 0] = [1e-3, -1e-3]
    z = rk4_network(z0, np.stack([np.stack([b_r, -b_r], -1), np.stack([b_h, -b_h], -1)], 1),
                    p, 0.005, 400)
    zr, zh = rk4_pair(np.full(7, 1e-3), np.zeros(7), b_r, b_h, p.pair, 0.005, 400)
    np.testing.assert_allclose(z[:, 0, 0], zr, rtol=0, atol=1e-12)
    np.testing.assert_allclose(z[:, 1, 0], zh, rtol=0, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(n_options, st.lists(value, min_size=24, max_size=24), weight, weight)
def test_the_subspace_is_kept_exactly(n: int, raw: list[float], beta: float, delta: float) -> None:
    p = OptionsParams(n_options=n, beta=beta, delta=delta)
    z0 = on_subspace(np.array(raw[: 2 * n]).reshape(2, n))
    b = on_subspace(np.array(raw[-2 * n :]).reshape(2, n))
    z = rk4_network(z0, b, p, 0.002, 200)
    assert np.all(z.sum(axis=-1) == 0.0)  # by construction, not to a tolerance
    assert np.all(np.isfinite(z))
    assert np.abs(network_rate(z, b, p).sum(axis=-1)).max() < 1e-12


@settings(max_examples=40, deadline=None)
@given(n_options, st.lists(value, min_size=24, max_size=24), weight, weight, st.randoms())
def test_relabelling_options_relabels_the_flow(
    n: int, raw: list[float], beta: float, delta: float, rnd: object
) -> None:
    p = OptionsParams(n_options=n, beta=beta, delta=delta)
    perm = list(range(n))
    rnd.shuffle(perm)  # type: ignore[attr-defined]
    z = on_subspace(np.array(raw[: 2 * n]).reshape(2, n))
    b = on_subspace(np.array(raw[-2 * n :]).reshape(2, n))
    np.testing.assert_allclose(
        network_rate(z[:, perm], b[:, perm], p), network_rate(z, b, p)[:, perm], atol=1e-12
    )
    after = rk4_network(z[:, perm], b[:, perm], p, 0.002, 100)
    np.testing.assert_allclose(after, rk4_network(z, b, p, 0.002, 100)[:, perm], atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(n_options, st.lists(value, min_size=12, max_size=12), weight, weight)
def test_jacobian_is_the_derivative(n: int, raw: list[float], beta: float, delta: float) -> None:
    p = OptionsParams(n_options=n, beta=beta, delta=delta)
    z = on_subspace(np.array(raw[: 2 * n]).reshape(2, n)) * 0.3
    jac = network_jacobian(z, p)
    eps = 1e-6
    for c in range(2 * n):
        dz = np.zeros((2, n))
        dz.flat[c] = eps
        no_bias = np.zeros((2, n))
        column = (network_rate(z + dz, no_bias, p) - network_rate(z - dz, no_bias, p)) / (2 * eps)
        np.testing.assert_allclose(jac[:, c], column.ravel(), atol=1e-6)


def test_subspace_basis_is_orthonormal_and_zero_sum() -> None:
    for n in range(2, 7):
        q = subspace_basis(n)
        np.testing.assert_allclose(q.T @ q, np.eye(n - 1), atol=1e-12)
        np.testing.assert_allclose(q.sum(axis=0), 0.0, atol=1e-12)


def test_option_vector_leads_by_two_for_any_number_of_options() -> None:
    np.testing.assert_array_equal(option_vector(0, 2), [1.0, -1.0])
    np.testing.assert_array_equal(option_vector(1, 2), [-1.0, 1.0])
    for n in range(2, 7):
        for j in range(n):
            v = option_vector(j, n)
            assert abs(v.sum()) < 1e-12
            assert np.delete(v[j] - v, j) == pytest.approx(np.full(n - 1, 2.0))
    with pytest.raises(ValueError, match="option must be in 0..2"):
        option_vector(3, 3)


agent_values = st.builds(
    AgentParams,
    d=st.floats(0.1, 20.0), u=st.floats(0.0, 5.0), alpha=st.floats(-2.0, 2.0),
    gamma=st.floats(-10.0, 10.0),
)


@settings(max_examples=300)
@given(value, value, value, value, agent_values)
def test_the_two_option_kernel_is_the_general_form_at_two_options(x, social, b0, b1, agent):
    """At N_o = 2 (β = δ = 0) `agent_rates` computes eq 1 itself; the general form agrees."""
    z, s, b = np.array([x, -x]), np.array([social, -social]), np.array([b0, b1])
    kernel = agent_rates(z, s, b, agent)
    general = general_rates(z, s, b, agent)
    assert np.allclose(kernel, general, rtol=0.0, atol=1e-12)
    assert kernel[0] == -kernel[1]
    # and the kernel is eq 1's arithmetic, bit for bit
    from services.model.dynamics import opinion_rate

    assert kernel[0] == opinion_rate(x, social, 0.5 * (b0 - b1), agent.d, agent.u, agent.alpha,
                                     agent.gamma)


@given(st.integers(3, 6), st.lists(value, min_size=6, max_size=6), agent_values)
def test_beyond_two_options_the_rates_are_the_general_form(n, values, agent):
    z = on_subspace(np.array(values[:n]))
    s = on_subspace(np.array(values[::-1][:n]))
    assert np.array_equal(agent_rates(z, s, 0.0, agent), general_rates(z, s, 0.0, agent))
