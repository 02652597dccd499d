"""A store never takes damage quietly (issue 32 item 5).

Real SQLite files, damaged as a disk or a careless copy damages them: 8 kB of garbage written in
the middle of a session's pages, the file cut short. Opening one is refused in one line and the
file's bytes are left as they were; `nod store check` lists what is wrong; a session's end leaves
a checked backup; `--resume` refuses another rig's session and a complete one, changing nothing.
"""

from __future__ import annotations

import hashlib
import random
import shutil
import sqlite3
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.experiment import report
from services.experiment.resume import resume_problem
from services.model.params import NodConfig
from services.store import (
    DamagedStoreError,
    Sample,
    Store,
    StoreError,
    TrialRecord,
    backup_path,
    check_file,
    pack_landmarks,
)
from services.store import cli as store_cli

TRIALS, SAMPLES = 8, 600  # a session as the conductor stores it: 10 s of each trial at 60 Hz
LANDMARKS = pack_landmarks([(0.01 * i, 0.02 * i) for i in range(21)])


def fill(store: Store, session: str, participant: str, rig: str = "rig1",
         status: str | None = "complete", trials: int = TRIALS, seed: int = 0) -> None:
    """One session of real size: `trials` trials of SAMPLES samples with their landmarks."""
    rng = random.Random(seed)
    started = (seed + 1) * 10**12
    store.begin_session(session, participant, rig, seed, started, NodConfig().summary())
    for t in range(1, trials + 1):
        rec = TrialRecord(t, "consensus", "red", "high", 0.0, 0.0, started + t * 10**10,
                          started + t * 10**10 + 5 * 10**9, "red", "red", "C", 0, 0, 10, 1,
                          "human pressed")
        store.write_trial(session, rec, [
            Sample(started + i * 16_666_667, True, *(rng.random() for _ in range(9)),
                   LANDMARKS)
            for i in range(SAMPLES)
        ])
    if status is not None:
        store.finish_session(session, started + 10**11, status)


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A store of one complete session (8 trials × 600 samples, ≈ 1.5 MB, ≈ 370 pages)."""
    path = tmp_path_factory.mktemp("good") / "study.sqlite"
    store = Store(path)
    fill(store, "s1", "P01")
    store.close()
    return path


@pytest.fixture
def copy(good: Path, tmp_path: Path) -> Path:
    """The good store, copied into this test's folder."""
    return Path(shutil.copy(good, tmp_path / "study.sqlite"))


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def garbage(path: Path, offset: int, seed: int = 1, size: int = 8192) -> None:
    with path.open("r+b") as f:
        f.seek(offset)
        f.write(random.Random(seed).randbytes(size))


def cut(path: Path, n: int) -> None:
    with path.open("r+b") as f:
        f.truncate(path.stat().st_size - n)


def refused(path: Path) -> str:
    """Open the store; it must be refused, the file unchanged. The refusal's text."""
    before = digest(path)
    with pytest.raises(DamagedStoreError) as caught:
        Store(path)
    assert digest(path) == before  # nothing written: no table, no migration, no session
    text = str(caught.value)
    assert "\n" not in text and str(path) in text and f"nod store check --db {path}" in text
    return text


def test_the_good_store_is_big_enough_to_damage_in_the_middle(good: Path) -> None:
    assert good.stat().st_size > 1_000_000 and check_file(good) == []
    assert check_file(good, full=True) == []


def test_garbage_mid_file_is_refused_and_the_file_left_as_it_was(copy: Path) -> None:
    garbage(copy, copy.stat().st_size // 2)
    text = refused(copy)
    assert "is damaged" in text and "no backup" in text


@pytest.mark.parametrize("n", [1, 100, 1000, 4096, 100_000])
def test_a_file_cut_short_is_refused(copy: Path, n: int) -> None:
    cut(copy, n)  # 1 and 100 bytes cut only free space of the last page: SQLite sees nothing
    assert "cut short" in refused(copy)  # its size against its header, before SQLite reads it


def test_the_refusal_names_the_backup_when_there_is_one(copy: Path) -> None:
    store = Store(copy)
    backup = store.backup()
    store.close()
    garbage(copy, copy.stat().st_size // 2)
    text = refused(copy)
    assert f"copy {backup} in its place" in text and backup == backup_path(copy)


def test_a_file_that_is_no_database_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "notes.sqlite"
    path.write_text("participant,answer\nP01,7\n" * 10)
    assert "not a SQLite database" in refused(path)


def test_a_new_or_empty_file_is_a_new_store(tmp_path: Path) -> None:
    (tmp_path / "empty.sqlite").touch()
    for name in ("new.sqlite", "empty.sqlite"):
        Store(tmp_path / name).close()
        assert check_file(tmp_path / name, full=True) == []


@settings(max_examples=25, deadline=None)
@given(where=st.floats(0.0, 1.0), seed=st.integers(0, 2**32 - 1))
def test_whatever_8kb_of_garbage_breaks_opening_refuses(good: Path, tmp_path_factory,
                                                        where: float, seed: int) -> None:
    """Garbage anywhere past the header: the full check and the open agree, the file unchanged."""
    path = Path(shutil.copy(good, tmp_path_factory.mktemp("g") / "study.sqlite"))
    garbage(path, 100 + int(where * (path.stat().st_size - 100 - 8192)), seed)
    if check_file(path, full=True):
        refused(path)
    else:  # the garbage hit nothing SQLite reads (never seen: every page of it is in use)
        Store(path).close()


def test_nod_store_check_good_and_damaged(copy: Path, tmp_path: Path, capsys) -> None:
    assert store_cli.main(["check", "--db", str(copy)]) == 0
    assert capsys.readouterr().out.startswith(f"{copy}: ok")
    short = Path(shutil.copy(copy, tmp_path / "short.sqlite"))
    cut(short, 1000)
    garbage(copy, copy.stat().st_size // 2)
    before = digest(copy), digest(short)
    for path in (copy, short):
        assert store_cli.main(["check", "--db", str(path)]) == 1
        lines = capsys.readouterr().out.splitlines()
        assert 2 <= len(lines) <= 10 and all(ln.startswith(f"{path}: ") for ln in lines)
        assert "DAMAGED" in lines[-1]
    assert (digest(copy), digest(short)) == before
    assert store_cli.main(["check", "--db", str(tmp_path / "none.sqlite")]) == 2


def test_nod_report_refuses_a_damaged_store_in_one_line(copy: Path, capsys) -> None:
    garbage(copy, copy.stat().st_size // 2)
    before = digest(copy)
    assert report.main(["--db", str(copy)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "is damaged" in err
    assert digest(copy) == before


def test_nod_run_refuses_a_damaged_store_before_starting_anything(copy: Path, capsys) -> None:
    from services import run

    cut(copy, 1000)
    before = digest(copy)
    assert run.main(["--sim", "--db", str(copy)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "cut short" in err
    assert digest(copy) == before and not copy.with_suffix(".logs").exists()


def test_the_backup_is_a_checked_sqlite_file_with_the_same_sessions(copy: Path) -> None:
    store = Store(copy)
    fill(store, "s2", "P02", status="aborted", trials=2, seed=2)
    backup = store.backup()
    assert backup == copy.with_name("study.sqlite.backup")
    assert not backup.with_name(backup.name + ".tmp").exists()
    assert check_file(backup, full=True) == []
    with sqlite3.connect(backup) as db:  # one self-contained file: no WAL beside it needed
        assert db.execute("PRAGMA journal_mode").fetchone()[0] == "delete"
    copied = Store(backup)
    assert copied.sessions() == store.sessions() and len(copied.sessions()) == 2
    assert copied.trials("s2") == store.trials("s2")
    copied.close()
    store.close()


def test_a_damaged_store_never_replaces_its_last_good_backup(copy: Path) -> None:
    store = Store(copy)
    backup = store.backup()
    kept = digest(backup)
    garbage(copy, copy.stat().st_size // 2)  # under the open store, as a failing disk does
    store.db.execute("PRAGMA shrink_memory")  # the pages are read from the file again
    with pytest.raises(StoreError, match="fails its check"):
        store.backup()
    store.close()
    assert digest(backup) == kept and check_file(backup) == []
    assert not backup.with_name(backup.name + ".tmp").exists()


@pytest.fixture
def two_rigs(tmp_path: Path) -> Path:
    """rig1's store: s-done complete, s-open aborted after 3 trials, s-rig2 of rig2 aborted."""
    path = tmp_path / "rig1.sqlite"
    store = Store(path)
    fill(store, "s-done", "P01", trials=2, seed=1)
    fill(store, "s-open", "P02", status="aborted", trials=3, seed=2)
    fill(store, "s-rig2", "P03", rig="rig2", status="aborted", trials=3, seed=3)
    store.close()
    return path


def test_resume_refuses_another_rigs_session_and_a_complete_one(two_rigs: Path) -> None:
    store = Store(two_rigs)
    try:
        assert resume_problem(store, "s-open", "rig1") is None
        other = resume_problem(store, "s-rig2", "rig1")
        assert other is not None and "ran on rig 'rig2'" in other and "--rig rig2" in other
        done = resume_problem(store, "s-done", "rig1")
        assert done is not None and "is complete (2 trial(s) stored)" in done
        missing = resume_problem(store, "nope", "rig1")
        assert missing is not None and "no session 'nope'" in missing
    finally:
        store.close()


@pytest.mark.parametrize("command", ["run", "experiment"])
@pytest.mark.parametrize(("session", "rig", "says"), [
    ("s-rig2", "rig1", "ran on rig 'rig2'"),
    ("s-open", "rig2", "ran on rig 'rig1'"),
    ("s-done", "rig1", "is complete"),
])
def test_a_refused_resume_changes_nothing(two_rigs: Path, capsys, command: str, session: str,
                                          rig: str, says: str) -> None:
    from services import run
    from services.experiment import service

    before = digest(two_rigs)
    if command == "run":
        code = run.main(["--sim", "--db", str(two_rigs), "--resume", session, "--rig", rig])
    else:
        code = service.main(["--db", str(two_rigs), "--resume", session, "--rig", rig,
                             "--console", "off", "--clicks", "none"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err
    assert digest(two_rigs) == before  # the sessions' rig, status and finish time as they were


def test_a_store_is_a_context_manager(tmp_path):
    import sqlite3

    from services.store import Store

    with Store(tmp_path / "s.sqlite") as store:
        assert store.sessions() == []
    try:
        store.sessions()
    except sqlite3.ProgrammingError:
        pass  # closed when the block ended
    else:
        raise AssertionError("the store stayed open after its with block")
