"""Stores written before one `trials` table (schema version 2) open, migrated, and read alike.

The golden's store file was written by the code before the change (`tests/golden`); a store
with three-option sessions of that time is built here from that version's own table
definitions (`option_sets`, `option_trials` by box index), as its code wrote them.
"""

from __future__ import annotations

import csv
import shutil
import sqlite3
from pathlib import Path

import pytest

from services.experiment.export import main as export_main
from services.store import Store, StoreError
from tests.golden import golden

# The N-option tables of the store before version 2, as that version created them.
OLD_OPTION_TABLES = """
CREATE TABLE IF NOT EXISTS option_sets (
    session   TEXT PRIMARY KEY REFERENCES sessions(session),
    n_options INTEGER NOT NULL CHECK (n_options >= 2),
    names     TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS option_trials (
    session     TEXT NOT NULL REFERENCES option_sets(session),
    trial       INTEGER NOT NULL,
    mode        TEXT NOT NULL CHECK (mode IN ('dissensus', 'consensus')),
    option      INTEGER,
    gaze_level  TEXT NOT NULL,
    yaw         REAL NOT NULL,
    pitch       REAL NOT NULL,
    t_go_ns     INTEGER,
    t_end_ns    INTEGER,
    human       INTEGER,
    robot       INTEGER,
    outcome     TEXT CHECK (outcome IN ('C', 'CH', 'D', 'DH')),
    switches    INTEGER NOT NULL,
    violations  INTEGER NOT NULL,
    clicks      INTEGER,
    score       INTEGER NOT NULL,
    end_reason  TEXT NOT NULL,
    interrupted INTEGER NOT NULL DEFAULT 0,
    attempts    INTEGER NOT NULL DEFAULT 1,
    PRIMARY KEY (session, trial)
);
"""


def _rows(path: Path, query: str) -> list[tuple]:
    with sqlite3.connect(path) as db:
        return list(db.execute(query))


def _old_store(tmp_path: Path, robot: int = 2) -> Path:
    """The golden's store of today's code plus a three-option session stored as it stored it."""
    path = tmp_path / "old.sqlite"
    shutil.copy(golden.HERE / "store-2026-12.sqlite", path)
    with sqlite3.connect(path) as db:
        db.executescript(OLD_OPTION_TABLES)
        db.execute("INSERT INTO sessions VALUES ('o1', 'P09', 'rig1', 3, 5, 6, 'complete', "
                   "'{\"options\": [\"red\", \"blue\", \"green\"]}')")
        db.execute("INSERT INTO option_sets VALUES ('o1', 3, '[\"red\", \"blue\", \"green\"]')")
        db.execute("INSERT INTO option_trials VALUES ('o1', 1, 'dissensus', NULL, 'neutral', "
                   "0.0, 0.0, 10, 20, 0, 1, 'D', 0, 0, NULL, 0, 'human pressed', 0, 1)")
        db.execute("INSERT INTO option_trials VALUES ('o1', 4, 'consensus', 2, 'high', 0.5, "
                   f"0.1, 30, 40, 2, {robot}, 'C', 1, 0, 10, 2, 'human pressed', 0, 1)")
    return path


def test_the_golden_store_of_todays_code_opens_as_it_was(tmp_path: Path) -> None:
    path = tmp_path / "paper.sqlite"
    shutil.copy(golden.HERE / "store-2026-12.sqlite", path)
    query = "SELECT * FROM trials ORDER BY session, trial"
    before = _rows(path, query)
    assert _rows(path, "PRAGMA user_version") == [(0,)]
    with Store(path) as store:
        (session,) = [s["session"] for s in store.sessions()]
        assert store.option_names(session) == ("red", "blue")
    assert _rows(path, query) == before  # every value of every trial, as it was
    assert _rows(path, "PRAGMA user_version") == [(2,)]
    assert _rows(path, "SELECT n_options, names FROM option_sets") == [(2, '["red", "blue"]')]
    with Store(path) as store:  # opened again: nothing more to do, nothing changed
        assert [t for _, t in store.trials(session)][0].human in ("red", "blue")
    assert _rows(path, query) == before


def test_three_option_trials_of_the_old_table_move_into_trials_by_name(tmp_path: Path) -> None:
    path = _old_store(tmp_path)
    with Store(path) as store:
        trials = {t.trial: t for _, t in store.trials("o1")}
        assert store.option_names("o1") == ("red", "blue", "green")
    assert (trials[1].option, trials[1].human, trials[1].robot) == (None, "red", "blue")
    assert (trials[4].option, trials[4].human, trials[4].robot) == ("green", "green", "green")
    assert (trials[4].clicks, trials[4].score, trials[4].switches) == (10, 2, 1)
    names = {r[0] for r in _rows(path, "SELECT name FROM sqlite_master WHERE type = 'table'")}
    assert "option_trials" not in names and "option_sets" in names
    out = tmp_path / "csv"
    assert export_main(["--db", str(path), "--out", str(out)]) == 0
    with (out / "trials.csv").open() as fh:
        rows = [r for r in csv.DictReader(fh) if r["session"] == "o1"]
    assert [(r["trial"], r["option"], r["human"], r["robot"]) for r in rows] == [
        ("1", "NA", "red", "blue"), ("4", "green", "green", "green")]
    assert not (out / "option_trials.csv").exists()


def test_a_migration_that_cannot_finish_leaves_the_old_store_whole(tmp_path: Path) -> None:
    path = _old_store(tmp_path, robot=7)  # a box the session's option set does not have
    before = _rows(path, "SELECT * FROM option_trials")
    with pytest.raises(StoreError, match="robot 7, not a box of its option set"):
        Store(path)
    assert _rows(path, "SELECT * FROM option_trials") == before
    assert _rows(path, "PRAGMA user_version") == [(0,)]


def test_a_store_whose_fits_have_no_probability_opens_and_keeps_its_fits(tmp_path: Path) -> None:
    """The fits table before a 0/1 parameter's probability and the out-of-prior check had
    columns: opened, it gains them (NULL for the rows it had), and a new fit stores both."""
    from services.store.fits import FitRecord, read_fits, write_fits

    path = tmp_path / "fits.sqlite"
    shutil.copy(golden.HERE / "store-2026-12.sqlite", path)
    with sqlite3.connect(path) as db:
        assert {"probability", "prior_p"}.isdisjoint(
            r[1] for r in db.execute("PRAGMA table_info(fits)"))
        db.execute("INSERT INTO fits VALUES ('P01', 's1', 'speed', 0.4, 0.3, 0.5, 0.9, 'old', 1)")
    with Store(path) as store:
        (old,) = read_fits(store)
        assert (old.parameter, old.estimate, old.probability) == ("speed", 0.4, None)
        write_fits(store, [FitRecord("P02", "s2", "contrarian", 1.0, 0.0, 1.0, 0.9, "new", 2,
                                     0.62, 0.031)])
        assert [(f.probability, f.prior_p) for f in read_fits(store)] == [(None, None),
                                                                          (0.62, 0.031)]
    out = tmp_path / "csv"
    assert export_main(["--db", str(path), "--out", str(out)]) == 0
    with (out / "fits.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["parameter"], r["estimate"], r["probability"], r["prior_p"]) for r in rows] == [
        ("speed", "0.4", "NA", "NA"), ("contrarian", "1.0", "0.62", "0.031")]


def test_a_store_before_provenance_and_the_withdrawal_log_opens_and_keeps_its_rows(
    tmp_path: Path,
) -> None:
    """The golden's store has no `provenance` or `withdrawn_aggregates` table and a
    `withdrawals` table without who withdrew someone: opened, it gains them (an old withdrawal
    keeps its values, by whom '' and not aggregated), its version stays 2, its sessions have no
    provenance, and a new run's provenance is stored and exported."""
    from services.core.provenance import make_provenance
    from services.store.provenance import read_provenance, write_provenance
    from services.store.withdrawals import withdrawals

    path = tmp_path / "old.sqlite"
    shutil.copy(golden.HERE / "store-2026-12.sqlite", path)
    tables = "SELECT name FROM sqlite_master WHERE type = 'table'"
    with sqlite3.connect(path) as db:
        assert {"provenance", "withdrawn_aggregates"}.isdisjoint(r[0] for r in db.execute(tables))
        assert {"withdrawn_by", "aggregated"}.isdisjoint(
            r[1] for r in db.execute("PRAGMA table_info(withdrawals)"))
        db.execute("INSERT INTO withdrawals VALUES ('P77', 5, 'moved', 1, 6, '{\"trials\": 8}')")
    before = _rows(path, "SELECT * FROM trials ORDER BY session, trial")
    with Store(path) as store:
        (session,) = [s["session"] for s in store.sessions()]
        assert read_provenance(store) == []
        old = withdrawals(store)["P77"]
        assert (old.reason, old.deleted, old.counts, old.by, old.aggregated) == (
            "moved", True, {"trials": 8}, "", False)
        write_provenance(store, session, 9, make_provenance("2.0", "0123456789ab"))
    assert _rows(path, "PRAGMA user_version") == [(2,)]
    assert _rows(path, "SELECT * FROM trials ORDER BY session, trial") == before
    with Store(path) as store:  # opened again: nothing more to migrate, the row is there
        (run,) = read_provenance(store)
        assert (run.session, run.provenance.version, run.provenance.hosts) == (session, "2.0", {})
    out = tmp_path / "csv"
    assert export_main(["--db", str(path), "--out", str(out)]) == 0
    with (out / "provenance.csv").open() as fh:
        assert [(r["session"], r["params_hash"]) for r in csv.DictReader(fh)] == [
            (session, "0123456789ab")]
