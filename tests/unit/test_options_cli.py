"""`nod analyze thresholds --options N` as a user runs it: the two-option report unchanged, the
N-option one with the eigenvalues behind each point."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from services.analysis.thresholds_report import format_thresholds, thresholds_report
from services.model.dynamics import PairParams

ROOT = Path(__file__).resolve().parents[2]


def nod(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "services.cli", "analyze", "thresholds", *args],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )


def test_two_options_is_todays_report_byte_for_byte() -> None:
    plain, two = nod(), nod("--options", "2")
    assert plain.returncode == two.returncode == 0, plain.stderr + two.stderr
    assert two.stdout == plain.stdout == format_thresholds(thresholds_report(PairParams())) + "\n"
    assert nod("--json", "--options", "2").stdout == nod("--json").stdout


def test_three_options_json_reports_points_with_their_eigenvalues() -> None:
    res = nod("--options", "3", "--json")
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
    res = nod("--options", "4", "--delta", "-16", "--json")
    doc = json.loads(res.stdout)
    assert doc["u_agreement"] == pytest.approx(10 / 8.05) and doc["u_disagreement"] is None
    table = nod("--options", "4", "--beta", "0.5")
    assert table.returncode == 0 and "disagreement point u_d*" in table.stdout
    assert f"{10 / 7.55:.6g}" in table.stdout  # κ_dis = 0.05 − 0.5 + 8


def test_one_option_is_refused_in_one_line() -> None:
    res = nod("--options", "1")
    assert res.returncode == 2
    assert res.stderr.strip().splitlines()[-1].endswith("must be in [2, 64], got 1")
