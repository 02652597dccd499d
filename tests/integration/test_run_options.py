"""`nod run --sim --options 3`: a table of three boxes, every service its own process."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from services.store import Store
from services.store.options import OptionsStore, export_rows
from tests.processes import run_nod

from .conftest import free_port

pytestmark = pytest.mark.integration


def test_three_options_through_the_whole_distributed_loop(tmp_path: Path) -> None:
    db = tmp_path / "s.sqlite"
    # At 4x a 250 ms staleness bound is 62 ms of wall time: relaxed, as test_run_sim's runs
    run = run_nod("run", "--sim", "--options", "3", "--speed", "4", "--seed", "2", "--db",
                  str(db), "--listen", f"tcp/127.0.0.1:{free_port()}", "--stale-ms", "2000",
                  timeout=400)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "8 trials of 1 participant(s) stored" in run.stdout
    assert "green" in run.stdout  # the table names the options
    speaker = (tmp_path / "s.logs" / "speaker.log").read_text()
    assert "trial 8: go played" in speaker  # the countdown is heard on a table of three too

    store = Store(db)
    try:
        (session,) = [s["session"] for s in store.sessions()]
        assert store.sessions()[0]["status"] == "complete"
        options = OptionsStore(store)
        assert options.names(session) == ("red", "blue", "green")
        trials = options.trials(session)
        rows = export_rows(store.db)
    finally:
        store.close()
    assert [t.trial for t in trials] == list(range(1, 9))
    for t in trials:
        assert t.human in (0, 1, 2) and t.robot in (0, 1, 2), t
    control, consensus = trials[:3], trials[3:]
    assert {t.option for t in consensus} == {0, 1, 2}
    assert sum(t.outcome in ("D", "DH") for t in control) >= 2, control
    assert sum(t.human == t.option == t.robot for t in consensus) >= 4, consensus
    header, exported = rows["option_trials"]
    assert len(exported) == 8 and header[-3:] == ["option_name", "human_name", "robot_name"]
    assert rows["option_sets"][1] == [(session, 3, '["red", "blue", "green"]')]
    out = tmp_path / "csv"
    export = run_nod("export", "--db", str(db), "--out", str(out), timeout=60)
    assert export.returncode == 0, export.stderr
    with (out / "option_trials.csv").open() as fh:
        csv_rows = list(csv.DictReader(fh))
    assert [r["trial"] for r in csv_rows] == [str(i) for i in range(1, 9)]
    assert {r["human_name"] for r in csv_rows} <= {"red", "blue", "green"}
    assert (out / "option_sets.csv").read_text().count("\n") == 2  # header and the session


def test_three_rendered_boxes_found_by_vision(tmp_path: Path) -> None:
    """The camera path: the sim renders three coloured boxes, vision finds them and the hand."""
    db = tmp_path / "s.sqlite"
    run = run_nod("run", "--sim", "--options", "3", "--render", "--speed", "2", "--seed", "1",
                  "--db", str(db), "--listen", f"tcp/127.0.0.1:{free_port()}",
                  "--stale-ms", "2000", timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "8 trials of 1 participant(s) stored" in run.stdout
    vision_log = (tmp_path / "s.logs" / "vision.log").read_text()
    assert "found the 3 boxes" in vision_log
    store = Store(db)
    try:
        (session,) = [s["session"] for s in store.sessions()]
        trials = OptionsStore(store).trials(session)
    finally:
        store.close()
    assert len(trials) == 8 and all(t.robot in (0, 1, 2) for t in trials)
    assert sum(t.human in (0, 1, 2) for t in trials) >= 7  # the hand is tracked to its press


def test_flags_not_yet_there_for_options_are_refused_before_anything_starts(
    tmp_path: Path,
) -> None:
    run = run_nod("run", "--sim", "--options", "3", "--order", "RBG", "--db",
                  str(tmp_path / "s.sqlite"), "--listen", f"tcp/127.0.0.1:{free_port()}",
                  timeout=60)
    assert run.returncode != 0
    assert "--order: not yet with 3 options" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1
