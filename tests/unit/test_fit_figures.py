"""`nod fit`'s figures are readable: titles within their panels, no text overprinted or cut off,
no axis stretched over near-constant data (the figures are measured with the Agg renderer)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from matplotlib.figure import Figure

from services.fit.figures import draw_intervals, draw_predictive, value_limits, write_figures
from services.fit.report import MEANING, OUTCOME_KEYS
from tests.unit.figure_checks import assert_readable, titles_overhanging

# One parameter of each kind the fit reports, with its longest meanings (firm_contrarian's).
NAMES = ("gaze_gain", "reaction_s", "late_switcher", "firm_contrarian", "persistent_contrarian")


def fit_doc(n: int) -> dict[str, Any]:
    """A `nod fit` document of n people: gaze_gain spans decades (a log scale), reaction_s is
    near-constant (0.9997-1.0), late_switcher is 1 for all, persistent_contrarian 0 (p ~0.0002)."""
    rows = []
    for i in range(n):
        g = 1.5 + 3.0 * (i % 7)
        rows.append({
            "participant": f"P{i + 1:03d}", "session": f"s{i}", "trials": 8,
            "parameters": {
                "gaze_gain": {"estimate": g, "low": g / 2, "high": g * 4},
                "reaction_s": {"estimate": 0.9997 + 0.00003 * (i % 10), "low": 0.9997,
                               "high": 1.0},
                "late_switcher": {"estimate": 1.0, "probability": 1.0 - 0.0003 * (i % 2),
                                  "set": [1], "low": 1.0, "high": 1.0},
                "firm_contrarian": {"estimate": 0.0, "probability": 0.002 * (i % 3) + (
                    0.3 if i % 5 == 0 else 0.0), "set": [0, 1] if i % 5 == 0 else [0],
                    "low": 0.0, "high": 1.0 if i % 5 == 0 else 0.0},
                "persistent_contrarian": {"estimate": 0.0, "probability": 0.0001 * (i % 3),
                                          "set": [0], "low": 0.0, "high": 0.0},
            },
            "predictive": {
                "observed": dict(zip(OUTCOME_KEYS, (0.5, 0.25, 0.25, 0.0, 0.0), strict=True)),
                "simulated": dict(zip(OUTCOME_KEYS, (0.4, 0.3, 0.2, 0.1, 0.0), strict=True)),
                "observed_press_s": [2.5, 2.5001, 2.5],  # all but equal
                "simulated_press_s": [2.5, 2.5002, 2.5001, 2.5],
                "sessions": 10,
            },
        })
    check = [{"name": name, "scale": "log" if name == "gaze_gain" else "linear"}
             for name in NAMES]
    return {"participants": rows, "identifiable": list(NAMES),
            "not_identifiable": {"preference_mean": {}, "trust0": {}, "perception_delay_s": {}},
            "check": check, "level": 0.9, "meaning": {k: MEANING[k] for k in NAMES}}


@pytest.mark.parametrize("n", [1, 3, 20, 60])
@pytest.mark.parametrize("draw", [draw_intervals, draw_predictive])
def test_every_title_fits_its_panel(draw: Any, n: int, close: list[Figure]) -> None:
    fig = draw(fit_doc(n))
    close.append(fig)
    assert not titles_overhanging(fig)
    assert_readable(fig)


def _panel(fig: Figure, name: str) -> Any:
    return next(ax for ax in fig.axes if ax.get_ylabel() == name)


def test_near_constant_estimates_are_not_stretched(close: list[Figure]) -> None:
    fig = draw_intervals(fit_doc(20))
    close.append(fig)
    lo, hi = _panel(fig, "reaction_s").get_ylim()
    assert hi - lo >= 0.1 * 1.0 - 1e-9  # 0.9997-1.0 drawn on at least 10 % of 1, not filling it
    assert lo <= 0.9997 and hi >= 1.0
    for name in ("late_switcher", "firm_contrarian", "persistent_contrarian"):  # probabilities
        lo, hi = _panel(fig, name).get_ylim()
        assert lo <= 0.0 and hi >= 1.0 and hi - lo <= 1.2, (name, lo, hi)
    gain = _panel(fig, "gaze_gain")
    assert gain.get_yscale() == "log"
    labels = [t.get_text() for t in gain.get_yticklabels() if t.get_text()]
    assert "10" in labels and not any("times" in t or "^" in t for t in labels)


def test_near_constant_press_times_are_not_stretched(close: list[Figure]) -> None:
    fig = draw_predictive(fit_doc(5))
    close.append(fig)
    top, bottom = fig.axes[:2]
    assert top.get_ylim() == (0.0, 1.0)
    lo, hi = bottom.get_ylim()
    assert hi - lo >= 0.1 * 2.5 - 1e-9 and lo <= 2.5 <= hi


@pytest.mark.parametrize(
    ("values", "span"),
    [([0.9997, 1.0], 0.1), ([0.0, 0.0], 1.0), ([-3.0, -3.0001], 0.3), ([0.2, 0.35], 0.15)],
)
def test_value_limits_keep_a_minimum_span(values: list[float], span: float) -> None:
    lo, hi = value_limits(values)
    assert hi - lo >= span - 1e-9 and lo <= min(values) and hi >= max(values)


def test_both_figures_are_written(tmp_path: Path) -> None:
    written = write_figures(fit_doc(3), tmp_path)
    assert [p.name for p in written] == ["fit_intervals.png", "fit_predictive.png"]
    assert all(p.read_bytes().startswith(b"\x89PNG") for p in written)
