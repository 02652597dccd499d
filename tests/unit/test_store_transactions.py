"""The store's transactions: every write is one, nested writes join the outer one, and a
simulated session is stored whole or not at all; samples written as rows equal samples written
as Samples."""

from __future__ import annotations

import sqlite3
import threading
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.cohort.person import load_cohort_params
from services.model.params import NodConfig
from services.sim.cohort import Job, simulate, store_session
from services.store import Sample, Store, TrialRecord
from services.store.store import sample_row


def record(trial: int = 1) -> TrialRecord:
    return TrialRecord(
        trial=trial, mode="dissensus", option="red", gaze_level="none", yaw=0.0, pitch=0.0,
        t_go_ns=10**9, t_end_ns=2 * 10**9, human="red", robot="red", outcome="C",
        switches=0, violations=0, clicks=10, score=5, end_reason="human pressed",
    )


def rows(db: Path, table: str) -> list[tuple]:
    con = sqlite3.connect(db)
    try:
        return sorted(con.execute(f"SELECT * FROM {table}").fetchall(), key=repr)
    finally:
        con.close()


def test_an_error_inside_an_outer_transaction_undoes_the_inner_writes(tmp_path: Path) -> None:
    store = Store(tmp_path / "s.db")
    with pytest.raises(RuntimeError), store.transaction():
        store.begin_session("s1", "P001", "rig1", 1, 0, {})
        store.write_trial("s1", record(), [])  # its own transaction joins the outer one
        raise RuntimeError("the writer fails half-way")
    assert store.sessions() == []
    assert store.trials() == []
    store.begin_session("s1", "P001", "rig1", 1, 0, {})  # the store is usable afterwards
    assert [s["session"] for s in store.sessions()] == ["s1"]
    store.close()


def test_an_outer_transaction_commits_once_at_its_end(tmp_path: Path) -> None:
    db = tmp_path / "s.db"
    store = Store(db)
    with store.transaction():
        store.begin_session("s1", "P001", "rig1", 1, 0, {})
        store.write_trial("s1", record(), [])
        assert rows(db, "sessions") == []  # another connection sees nothing before the commit
    assert len(rows(db, "sessions")) == 1 and len(rows(db, "trials")) == 1
    store.close()


def test_another_threads_write_waits_for_the_open_transaction(tmp_path: Path) -> None:
    """Nesting is per thread: a second thread's write neither joins the open transaction (and
    goes with its rollback) nor breaks it; it is stored once the first has ended."""
    store = Store(tmp_path / "s.db")
    started = threading.Event()
    errors: list[BaseException] = []

    def other() -> None:
        started.set()
        try:
            store.begin_session("s2", "P002", "rig1", 2, 0, {})
        except BaseException as exc:  # noqa: BLE001 - reported by the assertion below
            errors.append(exc)

    worker = threading.Thread(target=other)
    with pytest.raises(RuntimeError), store.transaction():
        store.begin_session("s1", "P001", "rig1", 1, 0, {})
        worker.start()
        assert started.wait(timeout=30)
        assert worker.is_alive()  # waiting for this transaction, not failing inside it
        store.write_trial("s1", record(), [])  # this transaction still works
        raise RuntimeError("roll back s1")
    worker.join(timeout=30)
    assert not worker.is_alive() and errors == []
    assert [s["session"] for s in store.sessions()] == ["s2"]
    assert store.trials() == []
    store.close()


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
maybe = st.none() | finite


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 2**62), st.booleans(), maybe, maybe, maybe, maybe,
                          maybe, maybe, maybe, maybe, maybe, st.none() | st.binary(max_size=16)),
                max_size=20))
def test_samples_as_rows_store_what_samples_store(tmp_path_factory, values) -> None:
    samples = [Sample(*v) for v in values]
    stored = []
    for how in ("samples", "rows"):
        db = tmp_path_factory.mktemp(how) / "s.db"
        store = Store(db)
        store.begin_session("s1", "P001", "rig1", 1, 0, {})
        if how == "samples":
            store.write_trial("s1", record(), samples)
        else:
            store.write_trial_rows("s1", record(), [sample_row(s) for s in samples])
        store.close()
        stored.append(rows(db, "samples"))
    assert stored[0] == stored[1]
    assert len(stored[0]) == len(samples)


@pytest.fixture(scope="module")
def cfg() -> NodConfig:
    return load_cohort_params(None)


def test_a_simulated_session_is_stored_whole_or_not_at_all(tmp_path: Path, cfg) -> None:
    job = Job(0, 3, cfg, True)
    trials = simulate(job)
    broken = list(trials)
    broken[5] = None  # type: ignore[call-overload]  # the writer fails at the sixth trial
    store = Store(tmp_path / "s.db")
    with pytest.raises(AttributeError):
        store_session(store, job, broken, "cohort")
    assert store.sessions() == [] and store.trials() == []
    store_session(store, job, trials, "cohort")
    assert [s["status"] for s in store.sessions()] == ["complete"]
    assert [t.trial for _, t in store.trials()] == list(range(1, 9))
    assert sum(len(store.samples("cohort-3", t.trial)) for t in trials) == sum(
        len(t.samples) for t in trials)
    store.close()
