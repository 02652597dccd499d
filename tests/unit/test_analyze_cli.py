"""`nod analyze …` as a user runs it: subprocesses, exit codes, JSON shapes, one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from services.analysis.thresholds_report import format_thresholds, thresholds_report
from services.model.dynamics import PairParams

ROOT = Path(__file__).resolve().parents[2]


def nod(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "services.cli", "analyze", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_thresholds_json_has_the_paper_numbers() -> None:
    res = nod("thresholds", "--json")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["u"] == pytest.approx(2.24)
    assert doc["u_d_star"] == pytest.approx(10 / 8.05)
    lams = {row["lambda"]: row["u_star"] for row in doc["u_star"]}
    assert lams[-1.0] == pytest.approx(10 / 8.05) and lams[1.0] is None
    assert doc["dissensus_regime"] is True
    assert sorted(doc["origin_jacobian_eigenvalues"]) == pytest.approx([-27.808, 8.032])


def test_thresholds_table_and_config(tmp_path: Path) -> None:
    res = nod("thresholds")
    assert res.returncode == 0 and "u_d*" in res.stdout
    cfg = tmp_path / "lab.toml"
    cfg.write_text("[decision.pair.robot]\nu = 1.0\n")
    doc = json.loads(nod("thresholds", "--json", "--params", str(cfg)).stdout)
    assert doc["u"] == 1.0 and doc["dissensus_regime"] is False


def test_equilibria_json() -> None:
    res = nod("equilibria", "--br", "0", "--bh", "0", "--json")
    assert res.returncode == 0, res.stderr
    eqs = json.loads(res.stdout)["equilibria"]
    assert sorted(e["stability"] for e in eqs) == ["saddle", "stable", "stable"]
    for e in eqs:
        assert len(e["eigenvalues"]) == 2 and all(len(v) == 2 for v in e["eigenvalues"])
    res = nod("equilibria", "--br=-3.24", "--bh=-3.24", "--json")
    (only,) = json.loads(res.stdout)["equilibria"]
    assert only["stability"] == "stable" and only["z_r"] < 0 and only["z_h"] < 0


def test_equilibria_png(tmp_path: Path) -> None:
    png = tmp_path / "nullclines.png"
    res = nod("equilibria", "--br", "3.24", "--bh", "3.24", "--png", str(png))
    assert res.returncode == 0, res.stderr
    assert "1 equilibria" in res.stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_nullclines_pair_is_fig_3b(tmp_path: Path) -> None:
    svg = tmp_path / "fig3b.svg"
    res = nod("nullclines", "--out", str(svg))
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    # b = ±(u + 1) = ±3.24 is past the unique-equilibrium bias: one stable point per panel,
    # mirror images of each other, on the side of the bias.
    assert lines[0].startswith("(a) 1 equilibria: stable (+0.142, +0.142)")
    assert lines[1].startswith("(b) 1 equilibria: stable (-0.142, -0.142)")
    text = svg.read_text()
    assert "(a)" in text and "(b)" in text
    res = nod("nullclines", "--offset", "-2", "--out", str(tmp_path / "near.png"))
    assert res.returncode == 0 and "(a) 3 equilibria" in res.stdout  # |b| = 0.24 < u: three
    res = nod("nullclines", "--out", str(tmp_path / "fig.jpg"))
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and ".png" in res.stderr


def test_sweep_writes_the_arrays(tmp_path: Path) -> None:
    out, png = tmp_path / "s.npz", tmp_path / "s.png"
    res = nod("sweep", "--grid", "9", "--range", "6", "--out", str(out), "--png", str(png))
    assert res.returncode == 0, res.stderr
    with np.load(out) as data:
        np.testing.assert_array_equal(data["b_r"], np.linspace(-6, 6, 9))
        np.testing.assert_array_equal(data["b_h"], np.linspace(-6, 6, 9))
        for key in ("consensus", "z_r", "z_h", "converged"):
            assert data[key].shape == (9, 9)
        assert data["consensus"][0, 0] and data["consensus"][8, 8]
        assert not data["consensus"][0, 8] and not data["consensus"][4, 4]
    assert png.stat().st_size > 1000


def test_sweep_help_states_initial_condition_and_criterion() -> None:
    res = nod("sweep", "--help")
    assert res.returncode == 0
    assert "z_r(0) = 1e-6" in res.stdout and "1e-9" in res.stdout


def test_square_claim_json() -> None:
    res = nod("square-claim", "--grid", "21", "--range", "6", "--json")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert set(doc["readings"]) == {"outside", "both"}
    assert 0.0 <= doc["readings"]["both"]["agree_fraction"] <= 1.0


def test_stuart_maxwell_json() -> None:
    res = nod("stuart-maxwell", "--table", "[[10,4,2,0],[0,0,0,0],[22,8,5,0],[0,0,0,0]]", "--json")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["statistic"] == pytest.approx(27.0) and doc["df"] == 2
    assert doc["p"] == pytest.approx(np.exp(-13.5))


@pytest.mark.parametrize(
    "args, needle",
    [
        (["stuart-maxwell", "--table", "[[1,2],[3,"], "not valid JSON"),
        (["stuart-maxwell", "--table", "[[1,2],[3]]"], "ragged"),
        (["stuart-maxwell", "--table", "[[1,-2],[3,4]]"], ">= 0"),
        (["stuart-maxwell", "--table", "[[3,0],[0,4]]"], "singular"),
        (["equilibria", "--br", "abc", "--bh", "0"], "--br"),
        (["equilibria", "--br", "nan", "--bh", "0"], "finite"),
        (["equilibria", "--br", "1"], "--bh"),
        (["sweep", "--grid", "1", "--out", "x.npz"], "--grid"),
        (["sweep", "--grid", "2.5", "--out", "x.npz"], "--grid"),
        (["sweep", "--range", "0", "--out", "x.npz"], "--range"),
        (["sweep", "--range", "-3", "--out", "x.npz"], "--range"),
        (["sweep", "--out", "/no/such/dir/x.npz"], "does not exist"),
        (["square-claim", "--grid", "x"], "--grid"),
        (["thresholds", "--params", "/no/such/file.toml"], "not found"),
        (["frobnicate"], "invalid choice"),
        ([], "choose a command"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args: list[str], needle: str) -> None:
    res = nod(*args)
    assert res.returncode == 2, (res.stdout, res.stderr)
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("nod analyze") and "error" in lines[0]
    assert needle in lines[0]
    assert "Traceback" not in res.stderr


def test_bad_config_key_is_one_line(tmp_path: Path) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[decision.pair.robot]\nuu = 1.0\n")
    res = nod("thresholds", "--params", str(cfg))
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and "uu" in res.stderr
    cfg.write_text("[decision.pair.robot]\ngamma = 1.0\n")  # no dissensus threshold
    res = nod("thresholds", "--params", str(cfg))
    assert res.returncode == 2 and "dissensus threshold" in res.stderr


def test_parse_formats() -> None:
    from services.analysis.figures import parse_formats

    assert parse_formats("png") == ("png",)
    assert parse_formats(" PDF, svg,pdf ,") == ("pdf", "svg")  # case, spaces, duplicates
    for bad in ("", ",", "jpg", "png,eps"):
        with pytest.raises(ValueError, match="png, pdf, svg"):
            parse_formats(bad)


# --- `nod analyze thresholds --options N`: the two-option report unchanged, the N-option
# one with the eigenvalues behind each point



def test_two_options_is_todays_report_byte_for_byte() -> None:
    plain, two = nod("thresholds", ), nod("thresholds", "--options", "2")
    assert plain.returncode == two.returncode == 0, plain.stderr + two.stderr
    assert two.stdout == plain.stdout == format_thresholds(thresholds_report(PairParams())) + "\n"
    two_json = nod("thresholds", "--json", "--options", "2").stdout
    assert two_json == nod("thresholds", "--json").stdout


def test_three_options_json_reports_points_with_their_eigenvalues() -> None:
    res = nod("thresholds", "--options", "3", "--json")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["n_options"] == 3
    assert doc["u_disagreement"] == pytest.approx(10 / 8.05, abs=1e-12)
    assert doc["u_agreement"] is None and doc["dissensus_regime"] is True
    by_pattern = {m["pattern"]: m for m in doc["modes"]}
    dis, agree = by_pattern["disagreement"], by_pattern["agreement"]
    assert dis["kappa"] == pytest.approx(8.05) and dis["adjacency_eigenvalue"] == pytest.approx(-1)
    assert dis["multiplicity"] == agree["multiplicity"] == 2
    assert dis["jacobian_eigenvalue"] == pytest.approx(-10 + 2.24 * 8.05)
    assert agree["u_star"] is None and agree["kappa"] == pytest.approx(0.05 - 8)


def test_beta_and_delta_move_the_points_and_print_a_table() -> None:
    # κ = (α − β) + (γ − δ) λ with γ = −8: δ = −16 makes γ − δ = +8, which turns the agreement
    # mode on (κ = 0.05 + 8 at λ = 1) and the disagreement one off (κ = 0.05 − 8 at λ = −1).
    res = nod("thresholds", "--options", "4", "--delta", "-16", "--json")
    doc = json.loads(res.stdout)
    assert doc["u_agreement"] == pytest.approx(10 / 8.05) and doc["u_disagreement"] is None
    table = nod("thresholds", "--options", "4", "--beta", "0.5")
    assert table.returncode == 0 and "disagreement point u_d*" in table.stdout
    assert f"{10 / 7.55:.6g}" in table.stdout  # κ_dis = 0.05 − 0.5 + 8


def test_one_option_is_refused_in_one_line() -> None:
    res = nod("thresholds", "--options", "1")
    assert res.returncode == 2
    assert res.stderr.strip().splitlines()[-1].endswith("must be in [2, 64], got 1")
