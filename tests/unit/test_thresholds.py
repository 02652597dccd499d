"""Bifurcation points (services/model/thresholds.py): the paper's Sec 4.3, the N_o-option modes,
and the two-option kernel against the general computation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from services.model.dynamics import AgentParams, OptionsParams, PairParams
from services.model.thresholds import (
    general_thresholds,
    option_thresholds,
    restricted_jacobian,
    thresholds,
)

weight = st.floats(min_value=-3.0, max_value=3.0, allow_nan=False)
n_options = st.integers(min_value=2, max_value=6)


def test_dissensus_threshold_is_computed_from_parameters():
    th = thresholds(PairParams())
    assert th.adjacency_eigenvalues == pytest.approx((-1.0, 1.0))
    # u_d* = d / (α + γ λ_min) = 10 / (0.05 + 8) = 10 / 8.05 (SPEC §1).
    assert th.u_d_star == pytest.approx(10.0 / 8.05)
    assert th.u_d_star == pytest.approx(1.2422, abs=1e-4)
    # λ = +1 gives α + γ = −7.95 < 0: no positive u*.
    assert th.u_star == (pytest.approx(10.0 / 8.05), None)
    assert th.dissensus_regime is True


def test_dissensus_regime_false_below_threshold():
    agent = AgentParams(u=1.0)
    assert thresholds(PairParams(robot=agent, human=agent)).dissensus_regime is False


def test_no_dissensus_threshold_with_positive_gamma():
    agent = AgentParams(gamma=8.0)
    with pytest.raises(ValueError, match="no dissensus threshold"):
        thresholds(PairParams(robot=agent, human=agent))


def test_origin_jacobian_eigenvalues():
    p = PairParams()
    a = p.robot
    # J(0,0) = [[−d + uα, uγ], [uγ, −d + uα]]: eigenvalues −d + uα ± uγ.
    expected = sorted([-a.d + a.u * a.alpha + a.u * a.gamma, -a.d + a.u * a.alpha - a.u * a.gamma])
    th = thresholds(p)
    assert th.origin_jacobian_eigenvalues == pytest.approx(tuple(expected))
    # u > u_d*: one unstable direction (the dissensus one), the origin is a saddle.
    assert th.origin_jacobian_eigenvalues[0] < 0 < th.origin_jacobian_eigenvalues[1]


def test_two_option_thresholds_are_todays() -> None:
    today = thresholds(PairParams())
    th = option_thresholds(OptionsParams(n_options=2))
    assert th.u_disagreement == pytest.approx(today.u_d_star, abs=1e-12)
    assert th.u_agreement is None and today.u_star[1] is None
    assert sorted(m.jacobian_eigenvalue for m in th.modes) == pytest.approx(
        today.origin_jacobian_eigenvalues, abs=1e-12
    )
    assert th.dissensus_regime is today.dissensus_regime is True


@pytest.mark.parametrize("n", [3, 4, 5])
def test_paper_parameters_keep_u_d_star_for_any_number_of_options(n: int) -> None:
    th = option_thresholds(OptionsParams(n_options=n))
    assert th.u_disagreement == pytest.approx(thresholds(PairParams()).u_d_star, abs=1e-12)
    assert [(m.pattern, m.multiplicity) for m in th.modes] == [
        ("agreement", n - 1),
        ("disagreement", n - 1),
    ]
    # every eigenvalue of the restricted Jacobian is one of the modes'
    eig = np.sort(np.linalg.eigvals(restricted_jacobian(OptionsParams(n_options=n))).real)
    want = np.sort(np.repeat([m.jacobian_eigenvalue for m in th.modes], n - 1))
    np.testing.assert_allclose(eig, want, atol=1e-10)


@settings(max_examples=40, deadline=None)
@given(n_options, weight, weight, st.floats(0.1, 2.0), st.floats(0.1, 2.0),
       st.floats(-10.0, 10.0), st.floats(-1.0, 1.0))
def test_modes_match_the_closed_form(
    n: int, beta: float, delta: float, a_rh: float, a_hr: float, gamma: float, alpha: float
) -> None:
    agent = AgentParams(gamma=gamma, alpha=alpha)
    p = OptionsParams(pair=PairParams(robot=agent, human=agent, a_rh=a_rh, a_hr=a_hr),
                      n_options=n, beta=beta, delta=delta)
    th = option_thresholds(p)
    lam = math.sqrt(a_rh * a_hr)
    want = sorted(alpha - beta + (gamma - delta) * x for x in (lam, -lam))
    got = [m.kappa for m in th.modes]
    if abs(want[1] - want[0]) < 1e-6:
        return  # the two modes coincide (γ = δ): one eigenvalue, no pattern to tell apart
    assert got == pytest.approx(want, abs=1e-9)
    for m in th.modes:
        agree = m.adjacency_eigenvalue is not None and m.adjacency_eigenvalue > 0
        assert m.pattern == ("agreement" if agree else "disagreement")
        assert m.multiplicity == n - 1
        assert m.u_star == (pytest.approx(agent.d / m.kappa) if m.kappa > 0 else None)


def _same_thresholds(a, b, tol: float) -> None:
    """Two OptionThresholds equal to `tol` in every number and equal in every label."""
    assert (a.n_options, a.u, a.d) == (b.n_options, b.u, b.d)
    assert [(m.pattern, m.multiplicity) for m in a.modes] == [
        (m.pattern, m.multiplicity) for m in b.modes
    ]
    for x, y in zip(a.modes, b.modes, strict=True):
        for name in ("kappa", "adjacency_eigenvalue", "u_star", "jacobian_eigenvalue"):
            vx, vy = getattr(x, name), getattr(y, name)
            assert (vx is None) == (vy is None), name
            if vx is not None:
                assert vx == pytest.approx(vy, rel=tol, abs=tol), name
    for name in ("u_agreement", "u_disagreement"):
        vx, vy = getattr(a, name), getattr(b, name)
        assert (vx is None) == (vy is None), name
        if vx is not None:
            assert vx == pytest.approx(vy, rel=tol, abs=tol), name
    assert a.dissensus_regime is b.dissensus_regime


@settings(max_examples=300, deadline=None)
@given(st.floats(0.1, 20.0), st.floats(0.0, 5.0), st.floats(-1.0, 1.0), st.floats(-10.0, 10.0),
       st.floats(0.1, 2.0), st.floats(0.1, 2.0), st.booleans())
def test_the_two_option_kernel_is_the_general_computation_at_two_options(
    d: float, u: float, alpha: float, gamma: float, a_rh: float, a_hr: float, negative: bool
) -> None:
    if abs(gamma) < 1e-3:
        return  # the two modes coincide (γ = 0): one eigenvalue, no pattern to tell apart
    sign = -1.0 if negative else 1.0  # both edges inhibitory: still a real, distinct spectrum
    # κ = α + γλ near 0 is a tipping point at infinity: u* = d/κ then amplifies the general
    # computation's last bits without bound (κ = 1e-16 against an exact 0: "none" against 1e16),
    # so the comparison is of well-posed points; κ itself is compared to 1e-12 everywhere else.
    lam = math.sqrt(a_rh * a_hr)
    kappas = (alpha + gamma * lam, alpha - gamma * lam)
    assume(min(abs(k) for k in kappas) > 1e-3)
    agent = AgentParams(d=d, u=u, alpha=alpha, gamma=gamma)
    p = OptionsParams(pair=PairParams(robot=agent, human=AgentParams(), a_rh=sign * a_rh,
                                      a_hr=sign * a_hr), n_options=2)
    # u* = d/κ carries κ's 1e-12 relative to 1/|κ| (at most 1e-9 here)
    _same_thresholds(option_thresholds(p), general_thresholds(p),
                     1e-12 / min(1.0, *(abs(k) for k in kappas)))


def test_the_kernel_is_sec_4_3_bit_for_bit() -> None:
    """At the paper's parameters the kernel's u* and eigenvalues are `thresholds`' own floats."""
    today = thresholds(PairParams())
    th = option_thresholds(OptionsParams(n_options=2))
    assert th.u_disagreement == today.u_d_star
    assert [m.u_star for m in th.modes] == list(reversed(today.u_star))
    assert [m.adjacency_eigenvalue for m in th.modes] == list(reversed(today.adjacency_eigenvalues))


@pytest.mark.parametrize("n", [3, 4])
def test_beyond_two_options_the_thresholds_are_the_general_computation(n: int) -> None:
    p = OptionsParams(n_options=n)
    assert option_thresholds(p) == general_thresholds(p)
