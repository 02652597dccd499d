"""Equilibria of eqs 1-2 (Fig 3b): completeness, uniqueness, stability, and the paper's claims."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.analysis.equilibria import (
    _by_multistart,
    box,
    classify,
    deltas,
    find_equilibria,
)
from services.analysis.fields import max_rate
from services.model.dynamics import AgentParams, PairParams, jacobian, rk4_pair

P = PairParams()
U = P.robot.u
BIAS = st.floats(min_value=-6.0, max_value=6.0, allow_nan=False)
NON_MONOTONE = AgentParams(d=1.0, u=3.0, alpha=1.0, gamma=-1.0)  # d < u α: reduction impossible


def _index_sum(eqs) -> int:
    """Poincaré index sum: +1 per node/focus, −1 per saddle (must be 1 inside the box)."""
    return sum(1 if e.stability in ("stable", "unstable") else -1 for e in eqs)


def _check_consistent(eqs, b_r: float, b_h: float, p: PairParams) -> None:
    half_r, half_h = box(b_r, b_h, p)
    for e in eqs:
        d1, d2 = deltas(e.z_r, e.z_h, b_r, b_h, p)
        assert abs(d1) < 1e-10 and abs(d2) < 1e-10
        assert abs(e.z_r) <= half_r and abs(e.z_h) <= half_h
        expected = np.sort_complex(np.linalg.eigvals(jacobian(e.z_r, e.z_h, p)))
        assert np.allclose(sorted(e.eigenvalues, key=lambda v: (v.real, v.imag)), expected)
        re = [v.real for v in e.eigenvalues]
        if e.stability == "stable":
            assert max(re) < 0
        elif e.stability == "saddle":
            assert min(re) < 0 < max(re)
        elif e.stability == "unstable":
            assert min(re) > 0
    pts = [(e.z_r, e.z_h) for e in eqs]
    for i, a in enumerate(pts):
        for b in pts[i + 1 :]:
            assert math.dist(a, b) > 1e-6, "duplicate equilibrium"
    assert _index_sum(eqs) == 1


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_paper_claim_single_stable_consensus_at_u_plus_one(sign: float) -> None:
    b = sign * (U + 1.0)
    eqs = find_equilibria(b, b, P)
    assert len(eqs) == 1
    (e,) = eqs
    assert e.stability == "stable" and e.consensus
    assert np.sign(e.z_r) == np.sign(e.z_h) == sign
    assert all(v.real < 0 for v in e.eigenvalues)
    _check_consistent(eqs, b, b, P)


def test_unbiased_pair_has_saddle_origin_and_two_dissensus_states() -> None:
    eqs = find_equilibria(0.0, 0.0, P)
    assert len(eqs) == 3
    origin = [e for e in eqs if abs(e.z_r) < 1e-12 and abs(e.z_h) < 1e-12]
    assert len(origin) == 1 and origin[0].stability == "saddle"
    stable = [e for e in eqs if e.stability == "stable"]
    assert len(stable) == 2
    for e in stable:
        assert not e.consensus
        assert e.z_r == pytest.approx(-e.z_h, abs=1e-12)  # antisymmetric pair
    assert stable[0].z_r == pytest.approx(-stable[1].z_r, abs=1e-12)
    # On z_r = −z_h = z the equilibrium solves d z = u tanh((α − γ) z).
    z = abs(stable[0].z_r)
    assert P.robot.d * z == pytest.approx(U * math.tanh((P.robot.alpha - P.robot.gamma) * z))
    _check_consistent(eqs, 0.0, 0.0, P)


def test_bistable_corner_has_three_equilibria() -> None:
    eqs = find_equilibria(2.1, 2.0, P)
    assert [e.stability for e in eqs].count("stable") == 2
    assert [e.stability for e in eqs].count("saddle") == 1
    _check_consistent(eqs, 2.1, 2.0, P)


def test_classify_labels() -> None:
    assert classify((-2 + 1j, -2 - 1j)) == "stable"
    assert classify((1 + 0j, 3 + 0j)) == "unstable"
    assert classify((-1 + 0j, 3 + 0j)) == "saddle"
    assert classify((0j, -3 + 0j)) == "non-hyperbolic"


def test_json_form_uses_re_im_pairs() -> None:
    doc = find_equilibria(0.0, 0.0, P)[0].as_dict()
    assert set(doc) == {"z_r", "z_h", "stability", "consensus", "eigenvalues"}
    assert all(len(pair) == 2 for pair in doc["eigenvalues"])


@pytest.mark.parametrize(
    "p",
    [
        PairParams(robot=NON_MONOTONE),  # falls back to the human's reduction
        PairParams(human=NON_MONOTONE),
        PairParams(robot=NON_MONOTONE, human=AgentParams(d=1.0, u=2.0, alpha=1.5, gamma=0.7)),
    ],
    ids=["robot-non-monotone", "human-non-monotone", "both-non-monotone"],
)
def test_other_paths_agree_with_index_theory(p: PairParams) -> None:
    for b_r, b_h in [(0.0, 0.0), (0.3, -0.2), (1.5, 1.0), (-2.0, 0.5)]:
        eqs = find_equilibria(b_r, b_h, p)
        _check_consistent(eqs, b_r, b_h, p)


def test_linear_pair_without_attention() -> None:
    p = PairParams(robot=AgentParams(u=0.0), human=AgentParams(u=0.0))
    eqs = find_equilibria(2.0, -3.0, p)
    assert len(eqs) == 1
    assert (eqs[0].z_r, eqs[0].z_h) == pytest.approx((0.2, -0.3))
    with pytest.raises(ValueError, match="u > 0"):
        deltas(0.0, 0.0, 0.0, 0.0, p)


def test_rejects_non_finite_bias() -> None:
    with pytest.raises(ValueError, match="finite"):
        find_equilibria(float("nan"), 0.0, P)


@settings(max_examples=25, deadline=None)
@given(b_r=BIAS, b_h=BIAS)
def test_matches_independent_multistart_newton(b_r: float, b_h: float) -> None:
    eqs = find_equilibria(b_r, b_h, P)
    brute = _by_multistart(b_r, b_h, P, n=61)
    distinct: list[tuple[float, float]] = []
    for pt in brute:
        if all(math.dist(pt, q) > 1e-7 for q in distinct):
            distinct.append(pt)
    assert len(distinct) == len(eqs)
    for pt in distinct:
        assert min(math.dist(pt, (e.z_r, e.z_h)) for e in eqs) < 1e-8


@settings(max_examples=30, deadline=None)
@given(b_r=BIAS, b_h=BIAS, seed=st.integers(0, 2**32 - 1))
def test_random_biases_long_rk4_ends_on_a_returned_stable_equilibrium(
    b_r: float, b_h: float, seed: int
) -> None:
    eqs = find_equilibria(b_r, b_h, P)
    _check_consistent(eqs, b_r, b_h, P)
    stable = np.array([(e.z_r, e.z_h) for e in eqs if e.stability == "stable"])
    assert len(stable) >= 1
    rng = np.random.default_rng(seed)
    z_r0, z_h0 = rng.uniform(-1.5, 1.5, size=(2, 16))
    br, bh = np.full(16, b_r), np.full(16, b_h)
    z_r, z_h = rk4_pair(z_r0, z_h0, br, bh, P, 0.02, 1500)  # 30 s (fixed points = equilibria)
    settled = max_rate(z_r, z_h, br, bh, P) < 1e-8
    slowest = min(abs(v.real) for e in eqs for v in e.eigenvalues)
    if slowest > 1.0:  # near a bifurcation (e.g. b_r = b_h = 2.5) convergence is very slow
        assert settled.all()
    for x, y in zip(z_r[settled], z_h[settled], strict=True):
        assert np.min(np.hypot(stable[:, 0] - x, stable[:, 1] - y)) < 1e-6
