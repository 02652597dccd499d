"""Bias sweep (Fig 3a): the fast solver reproduces the plain RK4 baseline; square claim check."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.analysis.equilibria import find_equilibria
from services.analysis.fields import is_stable, max_rate
from services.analysis.square_claim import check_square_claim, square_claim
from services.analysis.sweep import (
    DEFAULT_Z0,
    bias_grid,
    consensus_map,
    save_npz,
    sweep,
    sweep_rk4,
)
from services.model.dynamics import AgentParams, PairParams, jacobian_entries

P = PairParams()
U = P.robot.u


def _assert_same(fast, base) -> None:
    np.testing.assert_array_equal(fast.consensus, base.consensus)
    ok = base.converged
    assert ok.mean() > 0.9
    assert np.all(fast.converged[ok])
    assert np.max(np.abs(fast.z_r - base.z_r)[ok]) < 1e-6
    assert np.max(np.abs(fast.z_h - base.z_h)[ok]) < 1e-6


@pytest.fixture(scope="module")
def grid_pair():
    b = bias_grid(25, 6.0)
    return sweep(b, b, P), sweep_rk4(b, b, P)


def test_fast_sweep_matches_baseline_on_small_grid(grid_pair) -> None:
    fast, base = grid_pair
    assert fast.method == "newton" and base.method == "rk4"
    _assert_same(fast, base)
    assert 0.05 < fast.consensus.mean() < 0.5  # both consensus corners exist, most is dissensus


def test_fast_sweep_matches_baseline_in_the_multistable_corner() -> None:
    # Around (±u, ±u) several stable equilibria coexist: the initial condition decides.
    b = np.concatenate([np.linspace(-2.7, -1.9, 9), np.linspace(1.9, 2.7, 9)])
    fast, base = sweep(b, b, P), sweep_rk4(b, b, P)
    _assert_same(fast, base)
    assert fast.consensus.any() and not fast.consensus.all()


def test_converged_points_are_stable_equilibria(grid_pair) -> None:
    fast, _ = grid_pair
    BR, BH = np.meshgrid(fast.b_r, fast.b_h)
    ok = fast.converged
    assert np.all(max_rate(fast.z_r, fast.z_h, BR, BH, P)[ok] < fast.tol)
    assert np.all(is_stable(jacobian_entries(fast.z_r, fast.z_h, P))[ok])


def test_steady_state_is_one_of_the_equilibria(grid_pair) -> None:
    fast, _ = grid_pair
    for i, j in [(0, 0), (12, 12), (3, 20), (24, 24), (18, 5)]:
        eqs = find_equilibria(fast.b_r[j], fast.b_h[i], P)
        stable = [(e.z_r, e.z_h) for e in eqs if e.stability == "stable"]
        z = (fast.z_r[i, j], fast.z_h[i, j])
        assert min(np.hypot(a - z[0], b - z[1]) for a, b in stable) < 1e-9


def test_unbiased_pair_ends_in_dissensus_leaning_as_started() -> None:
    # b = 0: the origin is a saddle; the 1e-6 robot lean picks the (z_r > 0, z_h < 0) state.
    res = sweep(np.array([0.0]), np.array([0.0]), P)
    assert not res.consensus[0, 0] and res.converged[0, 0]
    assert res.z_r[0, 0] > 0 > res.z_h[0, 0]
    assert DEFAULT_Z0 == (1e-6, 0.0)


def test_grid_orientation_rows_are_human_bias() -> None:
    b_r = np.array([-6.0, 6.0])
    b_h = np.array([-6.0, 0.0, 6.0])
    res = sweep(b_r, b_h, P)
    assert res.z_r.shape == (3, 2)
    assert res.consensus[0, 0] and res.consensus[2, 1]  # both blue, both red
    assert not res.consensus[0, 1] and not res.consensus[2, 0]
    assert np.all(res.z_r[:, 0] < 0) and np.all(res.z_r[:, 1] > 0)  # columns: robot bias
    assert np.all(res.z_h[0, :] < 0) and np.all(res.z_h[2, :] > 0)  # rows: human bias


def test_consensus_map_uses_signs() -> None:
    z_r = np.array([0.1, -0.1, 0.1, 0.0, 1e-12, 1e-3])
    z_h = np.array([0.2, -0.2, -0.2, 0.0, -1e-12, 0.0])
    # Both undecided (sgn 0 = sgn 0) is consensus in the paper's formal sense; one is not.
    assert consensus_map(z_r, z_h).tolist() == [True, True, False, True, True, False]


@pytest.mark.parametrize("n, r", [(1, 6.0), (0, 6.0), (5, 0.0), (5, -1.0), (5, float("inf"))])
def test_bias_grid_rejects_bad_input(n: int, r: float) -> None:
    with pytest.raises(ValueError):
        bias_grid(n, r)


def test_bias_grid_is_linspace() -> None:
    np.testing.assert_array_equal(bias_grid(121, 6.0), np.linspace(-6, 6, 121))


def test_save_npz_round_trip(tmp_path, grid_pair) -> None:
    fast, _ = grid_pair
    path = tmp_path / "s.npz"
    save_npz(fast, path, P)
    with np.load(path) as data:
        for key in ("b_r", "b_h", "consensus", "z_r", "z_h", "converged"):
            np.testing.assert_array_equal(data[key], getattr(fast, key))
        assert data["consensus"].dtype == bool and data["consensus"].shape == (25, 25)
        assert tuple(data["z0"]) == DEFAULT_Z0
        assert json.loads(str(data["params"]))["robot"]["u"] == U


@settings(max_examples=6, deadline=None)
@given(
    biases=st.lists(st.floats(-6.0, 6.0, allow_nan=False), min_size=2, max_size=4, unique=True),
    gamma=st.sampled_from([-8.0, -4.0, 3.0]),
)
def test_fast_matches_baseline_for_random_biases(biases: list[float], gamma: float) -> None:
    agent = AgentParams(gamma=gamma)
    p = PairParams(robot=agent, human=agent)
    b = np.array(sorted(biases))
    fast, base = sweep(b, b, p), sweep_rk4(b, b, p)
    ok = base.converged  # (with γ = −4 the origin can be a slow stable node)
    np.testing.assert_array_equal(fast.consensus[ok], base.consensus[ok])
    assert np.all(np.abs(fast.z_r - base.z_r)[ok] < 1e-6)
    assert np.all(np.abs(fast.z_h - base.z_h)[ok] < 1e-6)


def test_progress_is_reported_up_to_one() -> None:
    seen: list[float] = []
    b = bias_grid(5, 6.0)
    sweep(b, b, P, progress=seen.append)
    assert seen and seen[-1] == pytest.approx(1.0) or seen[-1] > 0.99
    assert all(0.0 <= f <= 1.0 for f in seen)


def test_the_sweep_bar_is_drawn_on_stderr_only_on_a_terminal(capsys, monkeypatch, tmp_path):
    from services.analysis.cli import main

    argv = ["sweep", "--grid", "5", "--out", str(tmp_path / "s.npz")]
    assert main(argv) == 0
    quiet = capsys.readouterr()  # captured: not a terminal, so no bar
    assert quiet.err == "" and quiet.out.startswith("wrote ")
    monkeypatch.setenv("TTY_COMPATIBLE", "1")  # rich: treat stderr as a terminal
    assert main(argv) == 0
    drawn = capsys.readouterr()
    assert "sweep 5×5" in drawn.err and "100%" in drawn.err and "━" not in drawn.out
    assert main([*argv, "--no-progress"]) == 0
    assert capsys.readouterr().err == ""


def test_square_claim_readings() -> None:
    b = np.array([-3.0, -1.0, 1.0, 3.0])
    outside = square_claim(b, b, U, "outside")
    both = square_claim(b, b, U, "both")
    # [i, j] = (b_h[i], b_r[j]); (b_r, b_h) = (3, 1): outside the square, not both beyond u.
    assert outside[2, 3] and not both[2, 3]
    assert both[3, 3] and both[0, 0] and not both[0, 3]
    with pytest.raises(ValueError):
        square_claim(b, b, U, "inside")  # type: ignore[arg-type]


def test_square_claim_report_on_computed_map(grid_pair) -> None:
    fast, _ = grid_pair
    report = check_square_claim(fast, U)
    both = report["readings"]["both"]
    outside = report["readings"]["outside"]
    assert both["agree_fraction"] > 0.97
    assert outside["agree_fraction"] < both["agree_fraction"]
    # One bias far beyond u with the other small and same-signed is dissensus: "outside" fails.
    assert not outside["claim_is_sufficient"]
    assert outside["claim_consensus_computed_dissensus"]["count"] > 0
    assert report["points"] == 625
