"""`nod run`'s evidence: a log folder per run, never reused; a simulated person per seed, never
a stored one again; the lines of a log the operator must see."""

from __future__ import annotations

import argparse
from pathlib import Path

from services import run
from services.launch.rigs import next_seed
from services.launch.run_logs import LogWatch, run_folder
from services.store import Store


def test_each_run_gets_a_folder_of_its_own_even_in_the_same_second(tmp_path: Path) -> None:
    base = tmp_path / "s.logs"
    now = 1_700_000_000.0
    first, second, third = (run_folder(base, now) for _ in range(3))
    assert len({first, second, third}) == 3
    assert all(p.is_dir() and p.parent == base for p in (first, second, third))
    assert second.name == f"{first.name}-2" and third.name == f"{first.name}-3"


def _preflight(db: Path, *extra: str) -> argparse.Namespace:
    args = run.build_parser().parse_args(["--sim", "--db", str(db), *extra])
    assert run._preflight(args) is None
    return args


def test_two_runs_into_one_store_keep_both_runs_logs(tmp_path: Path) -> None:
    db = tmp_path / "s.sqlite"
    one, two = _preflight(db), _preflight(db)
    assert one.log_dir != two.log_dir
    assert one.log_dir.parent == two.log_dir.parent == tmp_path / "s.logs"
    given = _preflight(db, "--logs", str(tmp_path / "mine"))  # the operator's folder, as given
    assert given.log_dir == tmp_path / "mine" and given.log_dir.is_dir()


def _stored(db: Path, *people: tuple[str, int | None]) -> None:
    store = Store(db)
    for k, (who, seed) in enumerate(people):
        store.begin_session(f"s{k}", who, "rig1", seed, k + 1, {})
    store.close()


def test_a_participant_added_to_a_store_is_a_new_simulated_person(tmp_path: Path) -> None:
    db = tmp_path / "s.sqlite"
    assert _preflight(db).seed == 1  # a new store: seed 1, as before
    _stored(db, ("P01", 1))
    added = _preflight(db)
    assert (added.participant, added.seed) == ("P02", 2)  # not P01's seed again
    study = _preflight(db, "--participants", "3")
    assert study.ids == ["P02", "P03", "P04"] and study.seed == 2
    assert [run._participant(study, i).seed for i in range(3)] == [2, 3, 4]
    assert _preflight(db, "--seed", "1").seed == 1  # a seed asked for is the one run


def test_next_seed_goes_past_every_stored_seed_of_every_store(tmp_path: Path) -> None:
    a, b = tmp_path / "a.sqlite", tmp_path / "b.sqlite"
    _stored(a, ("P01", 1), ("P02", 7), ("X", None))
    _stored(b, ("P03", 3))
    stores = [Store(a), Store(b)]
    try:
        assert next_seed(stores) == 8
        assert next_seed([]) == 1
    finally:
        for s in stores:
            s.close()


def test_the_watch_hands_back_new_waiting_lines_once(tmp_path: Path) -> None:
    log = tmp_path / "experiment.log"
    watch = LogWatch(log)
    assert watch.new() == []  # not written yet
    said = "trial 2 ready: waiting for the operator — `nod experiment next` starts it"
    log.write_text(f"12:00 INFO nod.experiment: {said}\n{said}\nother\ntrial 2 ready: wait")
    assert watch.new() == [said]  # the log's line and the console's note: once
    with log.open("a") as fh:
        fh.write("ing for the operator (partial line done)\n")
    assert watch.new() == ["trial 2 ready: waiting for the operator (partial line done)"]
    assert watch.new() == []
    log.write_text("trial 3 (attempt 2) ready: waiting for the operator — x\n")  # a new log
    assert watch.new() == ["trial 3 (attempt 2) ready: waiting for the operator — x"]
