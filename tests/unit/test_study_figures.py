"""Figs 8a-8d, the power figure and the per-trial figure, readable at N = 10, 60 and 200.

Every check measures the drawn figure with matplotlib's Agg renderer (tests/unit/figure_checks):
no text overprints another, none is cut off, legends cover no data.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from matplotlib.figure import Figure

from services.analysis.power import TESTS, paper_implied
from services.analysis.power import draw as draw_power
from services.analysis.study import OUTCOMES, ParticipantOutcomes, analyze_study
from services.analysis.study_figures import DRAW, _grid_layout, draw_grid, spread
from services.analysis.trial_plot import draw as draw_trial
from services.analysis.trial_plot import trial_title
from services.model.closed_loop import run_offline_session
from services.model.params import NodConfig
from services.sim.cohort import offline_record
from services.store import Sample, Store
from tests.unit.figure_checks import assert_readable, boxes

ROOT = Path(__file__).resolve().parents[2]
# Outcome probabilities per phase: "varied" puts every category in both phases (16 flows, the
# hardest Fig 8b), "designed" is the simulator's (control all D), as `nod cohort` gives.
KINDS = {
    "varied": ([0.3, 0.05, 0.6, 0.05], [0.6, 0.2, 0.1, 0.1]),
    "designed": ([0.0, 0.0, 1.0, 0.0], [0.85, 0.08, 0.04, 0.03]),
}


def study(n: int, kind: str = "varied", seed: int = 0) -> dict[str, Any]:
    """The analysis document of n synthetic participants (a timeout every 17th)."""
    rng = np.random.default_rng(seed)
    control, experiment = KINDS[kind]
    parts = []
    for i in range(n):
        outcomes = [*rng.choice(OUTCOMES, 3, p=control), *rng.choice(OUTCOMES, 5, p=experiment)]
        by_trial: dict[int, str | None] = {t: str(o) for t, o in enumerate(outcomes, 1)}
        if i % 17 == 3:
            by_trial[5] = None
        parts.append(ParticipantOutcomes(f"P{i + 1:03d}", f"s{i}", "complete", by_trial))
    return analyze_study(parts)


@pytest.mark.parametrize("n", [10, 60, 200])
@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("key", list(DRAW))
def test_fig8_text_never_overprints_and_stays_inside(
    key: str, kind: str, n: int, close: list[Figure]
) -> None:
    fig = DRAW[key](study(n, kind))
    close.append(fig)
    assert_readable(fig)


def test_fig8d_statistic_sits_under_the_axis_label(close: list[Figure]) -> None:
    doc = study(60)
    fig = DRAW["8d"](doc)
    close.append(fig)
    found = dict(boxes(fig))
    label = found["experiment (trials 4-8)"]
    stat = next(b for text, b in found.items() if text.startswith("Stuart-Maxwell"))
    assert stat.y1 <= label.y0  # below the label, not on it
    text = next(t for t in found if t.startswith("Stuart-Maxwell"))
    t = doc["stuart_maxwell"]["control_vs_experiment"]
    assert f"p = {t['p']:.3g}" in text or f"p = {t['p']:.2e}" in text
    assert "Holm-adjusted p = " in text and "(5 tests)" in text


@pytest.mark.parametrize("n", [10, 60, 200])
def test_fig8b_labels_are_clear_of_the_nodes(n: int, close: list[Figure]) -> None:
    from matplotlib.patches import Rectangle

    fig = DRAW["8b"](study(n))
    close.append(fig)
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    nodes = [p.get_window_extent(renderer) for p in fig.axes[0].patches
             if isinstance(p, Rectangle)]
    assert len(nodes) >= (8 if n == 200 else 5)  # (nearly) every category on both sides
    for text, box in boxes(fig):
        for node in nodes:
            w = min(box.x1, node.x1) - max(box.x0, node.x0)
            h = min(box.y1, node.y1) - max(box.y0, node.y0)
            assert w <= 0.5 or h <= 0.5, f"{text!r} lies on a node"


def test_fig8a_legend_is_off_the_bars(close: list[Figure]) -> None:
    fig = DRAW["8a"](study(200, "designed"))  # trials 1-3: bars at 100 %
    close.append(fig)
    ax = fig.axes[0]
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    legend = ax.get_legend().get_window_extent(renderer)
    assert legend.y0 >= ax.get_window_extent(renderer).y1 - 0.5


@pytest.mark.parametrize("n", [10, 40, 41, 60, 80, 81, 200, 1000])
def test_fig8c_stays_page_sized(n: int, close: list[Figure]) -> None:
    doc = study(n, "designed")
    fig = draw_grid(doc)
    close.append(fig)
    width, height = fig.get_size_inches()
    assert width <= 8.0 and height <= 8.0, (width, height)
    blocks, rows, letters = _grid_layout(n)
    assert len(fig.axes) == blocks and blocks * rows >= n and letters == (n <= 80)
    cells = sum(len(ax.texts) for ax in fig.axes)
    assert cells == (8 * n if letters else 0)
    ids = [t.get_text() for ax in fig.axes for t in ax.get_yticklabels()]
    if n <= 200:  # every participant is named up to 200; beyond, every k-th
        assert ids == list(doc["grid"])
    else:
        assert 0 < len(ids) < n and set(ids) <= set(doc["grid"])
    if n <= 200:
        assert_readable(fig)


@given(
    st.lists(st.floats(min_value=0, max_value=100), min_size=1, max_size=20),
    st.floats(min_value=0.5, max_value=5),
)
def test_spread_keeps_labels_apart_and_near(ys: list[float], gap: float) -> None:
    out = spread(ys, gap, 0.0, 100.0)
    order = sorted(out)
    assert all(b - a >= gap - 1e-9 for a, b in zip(order, order[1:], strict=False))
    if len(ys) * gap <= 100:  # room for all: inside the bounds
        assert all(-1e-9 <= y <= 100 + 1e-9 for y in out)
    apart = sorted(ys)
    if all(b - a >= gap for a, b in zip(apart, apart[1:], strict=False)):
        assert out == pytest.approx(ys)  # nothing to move


def _power_doc() -> dict[str, Any]:
    # The power document as `nod analyze power` writes it: per correction (Holm, uncorrected),
    # with the paper's implied power beside the uncorrected panel.
    sizes = [10, 20, 40, 60]
    power = {
        "control_vs_experiment": [1.0, 1.0, 1.0, 1.0],
        "trial_4_vs_5": [0.0, 0.06, 0.18, 0.29],
        "trial_5_vs_6": [0.02, 0.05, 0.28, 0.49],
        "trial_6_vs_7": [0.0, 0.01, 0.05, 0.05],  # low at 60: where the old legend sat
        "trial_7_vs_8": [0.02, 0.08, 0.33, 0.55],
    }
    scale = {"holm": 1.0, "none": 1.3}
    results = [
        {
            "participants": n,
            "runs": 100,
            "power": {c: {t: min(1.0, power[t][k] * f) for t in TESTS} for c, f in scale.items()},
            "ci95": {c: {t: [max(0.0, min(1.0, power[t][k] * f) - 0.08),
                             min(1.0, power[t][k] * f + 0.08)] for t in TESTS}
                     for c, f in scale.items()},
        }
        for k, n in enumerate(sizes)
    ]
    return {"alpha": 0.05, "results": results, "paper_implied": paper_implied(sizes)}


def test_power_legend_hides_no_point(close: list[Figure]) -> None:
    fig = draw_power(_power_doc())
    close.append(fig)
    assert_readable(fig)
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    legend = fig.legends[0].get_window_extent(renderer)
    holm, none = fig.axes
    for ax in (holm, none):
        points = [
            ax.transData.transform(xy) for line in ax.lines  # type: ignore[union-attr]
            for xy in line.get_xydata() if np.all(np.isfinite(xy))  # type: ignore[union-attr]
        ]
        assert len(points) >= 5 * 4
        assert not any(legend.contains(x, y) for x, y in points)
    assert "Holm" in holm.get_title() and "uncorrected" in none.get_title()
    # the paper's implied power: a cross per test and N (51 among them) in the uncorrected panel
    crosses = [line for line in none.lines if line.get_marker() == "x" and len(line.get_xdata())]
    assert len(crosses) == 5 and all(51 in line.get_xdata() for line in crosses)  # type: ignore[operator]
    assert not any(line.get_marker() == "x" and len(line.get_xdata()) for line in holm.lines)


@pytest.fixture(scope="module")
def run_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A `nod run`-like store: a hex session id for participant P01, trials with samples."""
    cfg = NodConfig()
    path = tmp_path_factory.mktemp("trial") / "run.sqlite"
    store = Store(path)
    store.begin_session("3f9a0c1b2d4e", "P01", "sim", 0, 10**9, cfg.summary())
    for t in run_offline_session(cfg, 0, cohort=True, record=True):
        samples = [Sample(s.t_ns, True, *s[1:]) for s in t.samples]
        record = offline_record(t, cfg.protocol.trials[t.trial - 1], samples[0].t_ns)
        store.write_trial("3f9a0c1b2d4e", record, samples)
    store.finish_session("3f9a0c1b2d4e", 2 * 10**9)
    store.begin_session("77aa", "P02", "sim", 1, 3 * 10**9, cfg.summary())  # the latest
    store.close()
    return path


def _trial_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "services.cli", "analyze", "trial", *args],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )


def test_the_trial_figure_is_titled_by_participant(run_store: Path, close: list[Figure]) -> None:
    store = Store(run_store)
    rec = next(t for _, t in store.trials("3f9a0c1b2d4e") if t.trial == 4)
    samples = store.samples("3f9a0c1b2d4e", 4)
    store.close()
    title = trial_title("P01", rec)
    assert title.startswith(f"P01, trial 4 (consensus, O = {rec.option}): human ")
    fig = draw_trial(samples, rec, NodConfig().layout, title)
    close.append(fig)
    assert fig.get_suptitle() == title and "3f9a" not in title
    assert_readable(fig)
    for ax in fig.axes:  # legends outside every panel: no trace under them
        legend = ax.get_legend()
        if legend is not None:
            renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
            box, frame = legend.get_window_extent(renderer), ax.get_window_extent(renderer)
            assert box.y0 >= frame.y1 - 0.5 or box.y1 <= frame.y0 + 0.5


def test_a_trial_of_three_options_draws_its_boxes_by_name_and_says_where_its_opinions_are(
    run_store: Path, close: list[Figure]
) -> None:
    store = Store(run_store)
    rec = next(t for _, t in store.trials("3f9a0c1b2d4e") if t.trial == 4)
    samples = [replace(s, z_h=None, z_r=None, b_r=None)  # as a session of N options stores them
               for s in store.samples("3f9a0c1b2d4e", 4)]
    store.close()
    names = ("red", "blue", "green")
    fig = draw_trial(samples, rec, NodConfig().table(3), trial_title("P01", rec), names)
    close.append(fig)
    assert_readable(fig)
    texts = {t.get_text() for ax in fig.axes for t in ax.texts}
    assert set(names) <= texts
    assert "opinions over the options are vectors: not in the samples table" in texts
    table = fig.axes[3]
    assert len(table.patches) == 3  # one box per option


@pytest.mark.parametrize("trial", [1, 4, 7])
def test_z_r_has_its_own_axis_scaled_to_its_range(
    run_store: Path, trial: int, close: list[Figure]
) -> None:
    """ẑ_h reaches ±8 and z_r tenths: on ẑ_h's axis z_r was a flat line at 0."""
    store = Store(run_store)
    rec = next(t for _, t in store.trials("3f9a0c1b2d4e") if t.trial == trial)
    samples = store.samples("3f9a0c1b2d4e", trial)
    store.close()
    fig = draw_trial(samples, rec, NodConfig().layout, trial_title("P01", rec))
    close.append(fig)
    assert_readable(fig)

    def axis_of(prefix: str) -> Any:
        return next(ax for ax in fig.axes for line in ax.get_lines()
                    if str(line.get_label()).startswith(prefix))

    z_r = max(abs(s.z_r or 0.0) for s in samples)
    z_h = max(abs(s.z_h or 0.0) for s in samples)
    assert 0.05 < z_r < 1.0 and z_h > 5.0  # the case: z_r tenths, ẑ_h near the observer's ±8
    ax_r, ax_h = axis_of("z_r"), axis_of("ẑ_h")
    assert ax_r is not ax_h and axis_of("b_r") is ax_h
    lo, hi = ax_r.get_ylim()
    assert lo <= -z_r and hi >= z_r  # all of z_r in view ...
    assert hi - lo <= 2 * max(1.5 * z_r, 0.05)  # ... filling its axis, not ±8 of it
    assert lo == -hi and ax_h.get_ylim()[0] == -ax_h.get_ylim()[1]  # one zero line for both
    assert ax_h.get_ylim()[1] >= z_h
    assert "z_r" in ax_r.get_ylabel() and "ẑ_h" in ax_h.get_ylabel()


def test_a_z_r_of_zero_is_drawn_flat(run_store: Path, close: list[Figure]) -> None:
    store = Store(run_store)
    rec = next(t for _, t in store.trials("3f9a0c1b2d4e") if t.trial == 2)
    samples = [replace(s, z_r=1e-9 * (k % 2))
               for k, s in enumerate(store.samples("3f9a0c1b2d4e", 2))]
    store.close()
    fig = draw_trial(samples, rec, NodConfig().layout, "t")
    close.append(fig)
    ax_r = next(ax for ax in fig.axes for line in ax.get_lines()
                if str(line.get_label()).startswith("z_r"))
    assert ax_r.get_ylim() == pytest.approx((-0.05, 0.05))  # noise of 1e-9 is not a signal


@pytest.mark.parametrize(
    "who", [("--participant", "P01"), ("--session", "P01"), ("--session", "3f9a0c1b2d4e")]
)
def test_a_session_is_named_by_participant_or_id(
    run_store: Path, tmp_path: Path, who: tuple[str, str]
) -> None:
    res = _trial_cli("--db", str(run_store), *who, "--trial", "4", "--out", str(tmp_path))
    assert res.returncode == 0, res.stderr
    assert "participant P01, session 3f9a0c1b2d4e, trial 4" in res.stdout
    assert (tmp_path / "trial4.png").read_bytes().startswith(b"\x89PNG")


def test_naming_a_session_wrongly_says_what_there_is(run_store: Path, tmp_path: Path) -> None:
    for args, words in (
        (("--participant", "P09"), "no participant 'P09'"),
        (("--session", "P09"), "no session or participant 'P09'"),
        (("--participant", "P02"), "participant P02 has no stored trials"),
        ((), "has no trial 4"),  # the latest session, P02's, has none
        (("--participant", "P01", "--session", "77aa"), "not allowed with argument"),
    ):
        res = _trial_cli("--db", str(run_store), *args, "--trial", "4", "--out", str(tmp_path))
        assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
        assert words in res.stderr, res.stderr
    res = _trial_cli("--db", str(run_store), "--participant", "P01", "--trial", "9",
                     "--out", str(tmp_path))
    assert res.returncode == 2 and "stored: 1, 2, 3, 4, 5, 6, 7, 8" in res.stderr
