"""The fit's summaries: a stored session reads as its simulation does; the prior's draws."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from services.cohort.person import load_cohort_params
from services.fit.data import read_study
from services.fit.simulate import parameter_names, true_person, truth
from services.model import closed_loop
from services.model.closed_loop import run_offline_session
from services.model.geometry import TableLayout
from services.model.summaries import TrialPath, from_offline, read_trial, summarise, summary_names
from services.sim import cohort


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))))


def test_a_stored_cohort_reads_as_its_simulated_sessions(tmp_path):
    """`nod cohort`'s store, read by the fit, gives the summaries of the same sessions offline."""
    db = tmp_path / "study.sqlite"
    seed = 41
    assert cohort.main(["--participants", "2", "--seed", str(seed), "--db", str(db),
                        "--quiet", "--workers", "1"]) == 0
    cfg = load_cohort_params(None)
    study = read_study(db)
    people, skipped = study.people, study.skipped
    assert not skipped and not study.notes and [p.participant for p in people] == ["P001", "P002"]
    for i, person in enumerate(people):
        offline = run_offline_session(cfg, seed + i, cohort=True, record=True)
        stored = summarise(person.paths, person.layout)
        simulated = summarise(from_offline(offline), cfg.layout)
        assert stored.shape == (len(summary_names()),)
        assert _same(stored, simulated), np.flatnonzero(~np.isclose(stored, simulated))
        assert np.isfinite(stored).sum() > 60  # the summaries read something, not NaN
        assert person.outcomes == tuple(t.outcome for t in offline)


def test_true_person_is_the_person_the_cohort_simulates():
    """The fit's truth replays exactly the cohort's draw (traits and strategist flag)."""
    cfg = load_cohort_params(None)
    for seed in (3, 77):
        loop = closed_loop._PaperLoop(cfg, seed, cohort=True, clicks=10)
        params, kinds = true_person(cfg, seed)
        assert loop.person.p == params
        for kind, flag in (("late_switcher", "strategist"), ("contrarian", "contrarian"),
                           ("firm_contrarian", "firm"),
                           ("persistent_contrarian", "persistent")):
            assert getattr(loop.person, flag) == kinds[kind]
    # With persistent contrarians in the cohort, the fit's draw still replays the cohort's.
    person = dataclasses.replace(cfg.participant, contrarian_share=1.0, contrarian_persist=0.5)
    cfg = dataclasses.replace(cfg, participant=person)
    persistent = []
    for seed in range(12):
        loop = closed_loop._PaperLoop(cfg, seed, cohort=True, clicks=10)
        _, kinds = true_person(cfg, seed)
        assert loop.person.persistent == kinds["persistent_contrarian"]
        persistent.append(kinds["persistent_contrarian"])
    assert 0 < sum(persistent) < 12
    assert "persistent_contrarian" in parameter_names(person)


def test_the_fitted_parameters_are_the_traits_drawn_per_person():
    cfg = load_cohort_params(None)
    names = parameter_names(cfg.participant)
    assert {"preference_mean", "gaze_gain", "speed", "reaction_s"} <= set(names)
    assert "accel" not in names  # the same for everyone: nothing to fit
    params, kinds = true_person(cfg, 5)
    theta = truth(params, kinds, names)
    assert {"late_switcher", "contrarian", "firm_contrarian"} <= set(names)  # the shipped kinds
    assert theta[names.index("contrarian")] == float(kinds["contrarian"])
    assert theta[names.index("speed")] == params.speed
    assert theta[names.index("gaze_use")] == pytest.approx(params.gaze_gain * params.trust0)


def _path(ts: list[float], xs: list[float], ys: list[float], human: str | None = "red",
          yaw: float = 0.5, mode: str = "consensus") -> TrialPath:
    return TrialPath(4, mode, yaw, human, "red", 0, False, tuple(ts), tuple(xs), tuple(ys))  # type: ignore[arg-type]


def test_a_straight_reach_reads_its_onset_speed_and_press():
    """A hand resting 0.5 s, then moving at 0.3 units/s straight into the red box."""
    layout = TableLayout()
    ts = [i / 30 for i in range(150)]
    red = layout.red.center
    start = (0.5, 0.85)
    xs, ys = [], []
    for t in ts:
        s = min(1.0, max(0.0, (t - 0.5) * 0.3 / math.dist(start, red)))
        xs.append(start[0] + s * (red[0] - start[0]))
        ys.append(start[1] + s * (red[1] - start[1]))
    r = read_trial(_path(ts, xs, ys), layout)
    assert r is not None
    assert r.onset == pytest.approx(0.6, abs=0.04)  # 0.03 units at 0.3 units/s after 0.5 s
    assert r.speed == pytest.approx(0.3, rel=0.02)
    assert 0.5 + 0.5 < r.press < 0.5 + math.dist(start, red) / 0.3
    assert (r.turn, r.gaze_first, r.gaze_press) == (0.0, 1.0, 1.0)


def test_a_hand_that_heads_blue_then_presses_red_is_a_turn():
    layout = TableLayout()
    ts = [i / 30 for i in range(120)]
    xs = [0.5 - 0.15 * min(t, 1.0) + 0.5 * max(0.0, t - 1.0) for t in ts]
    ys = [0.85 - 0.3 * min(t, 2.0) for t in ts]
    r = read_trial(_path(ts, xs, ys, yaw=-0.5), layout)
    assert r is not None and r.turn == 1.0
    assert r.gaze_first == 1.0 and r.gaze_press == 0.0  # the eyes looked blue
    assert r.reversal == pytest.approx(1.0 - r.onset, abs=0.05)


def test_an_interrupted_or_empty_trial_reads_nothing():
    layout = TableLayout()
    assert read_trial(_path([], [], []), layout) is None
    values = summarise([_path([], [], [])], layout)
    assert np.isnan(values).all()  # nothing read: every summary missing, none made up


def test_reference_tables_are_cached_and_extended_never_resimulated(tmp_path):
    """Person i of every table is the same: a larger table extends a cached smaller one."""
    from services.fit.simulate import TABLE_SEED, Population, Simulated, reference_table

    cfg = load_cohort_params(None)
    p = len(parameter_names(cfg.participant))
    asked: list[int] = []

    def run(fn, jobs):  # stands in for the engine: records which people were simulated
        asked.extend(seed for _, seed in jobs)
        return [Simulated(seed, np.full(p, float(seed)), np.full(3, float(seed)), (), ())
                for _, seed in jobs]

    small, cached = reference_table(Population(cfg), 5, run, tmp_path)
    assert not cached and asked == [TABLE_SEED + i for i in range(5)]
    big, cached = reference_table(Population(cfg), 8, run, tmp_path)
    assert not cached and asked[5:] == [TABLE_SEED + i for i in range(5, 8)]
    assert np.array_equal(big.theta[:5], small.theta)
    again, cached = reference_table(Population(cfg), 6, run, tmp_path)
    assert cached and len(asked) == 8 and np.array_equal(again.theta, big.theta[:6])
    other = dataclasses.replace(cfg, participant=dataclasses.replace(cfg.participant, speed=0.4))
    reference_table(Population(other), 2, run, tmp_path)  # other traits: another table
    assert len(asked) == 10
