"""N_o-option dynamics: reduction to eq 1-2 and to the live decision model, the subspace, the
options' symmetry, the Jacobian and the bifurcation points."""

from __future__ import annotations

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
    network_jacobian,
    network_rate,
    on_subspace,
    option_vector,
    pair_rhs,
    rk4_network,
    rk4_pair,
    subspace_basis,
)

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
