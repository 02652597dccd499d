"""The session store: one SQLite file (WAL) with sessions, trials, samples and questionnaires.

Samples are decimated; cues hold the participant's countdown as the speaker played it;
questionnaires hold the post-session answers Q1-Q5 of paper Sec 8;
recordings link a session to the MCAP files `nod record` wrote of it (`nod experiment --record`);
participants hold consent and demographics, session_orders the O order each session ran and why
a participant got another session (`services.store.participants`).
A table added by a later version is created when an older file is opened (`CREATE TABLE IF NOT
EXISTS`); a column added to an existing table is added by `_migrate`.

Each trial is written in one transaction together with its samples, so a crash mid-trial loses
at most that trial's unfinished samples; a session left 'running' is reported when the store is
opened again. A trial's start is committed on its own (`open_attempts`) and closed by the
transaction that stores the trial or its interruption: an attempt still open when a session is
resumed was lost with its conductor, and `nod experiment --resume` stores it as interrupted.

A store never takes damage quietly: opening an existing file checks it first (its header and size,
then SQLite's `PRAGMA quick_check`, on a read-only connection) and a damaged one is refused
(`DamagedStoreError`, one line naming the file, its backup and `nod store check`) before anything is
written to it — no table created, no migration, no session appended. A conductor backs the store
up when its session ends (`Store.backup`: SQLite's online backup to `<db>.backup`, checked, then
renamed into place, so the last good backup is never replaced by a torn or damaged copy).
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
import struct
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import fields, replace
from operator import attrgetter
from pathlib import Path
from typing import Any

from services.model.geometry import COLOURS
from services.model.scoring import trial_points
from services.store import session_rows
from services.store.records import (
    CueRecord,
    Interruption,
    QuestionnaireRecord,
    RigEventRecord,
    SafetyEvent,
    Sample,
    TrialRecord,
)
from services.store.schema import FITS_SCHEMA, POLICY_SCHEMA, SCHEMA

log = logging.getLogger("nod.store")

# PRAGMA user_version of this schema: 2 is one `trials` table for every option set (a store of
# version 0 or 1 kept three or more options' trials in `option_trials`, by box index).
STORE_VERSION = 2

class StoreError(OSError):
    """The database file cannot be opened or is not a session database."""


class DamagedStoreError(StoreError):
    """The database file fails its integrity check: refused, nothing written to it."""


SQLITE_MAGIC = b"SQLite format 3\x00"
BACKUP_SUFFIX = ".backup"  # `<db>.backup`: the last good copy, written when a session ends
MAX_PROBLEMS = 10  # lines of SQLite's check kept (a torn file can list thousands)


def backup_path(path: str | Path) -> Path:
    """Where the store at `path` keeps its last backup: `<db>.backup` beside it."""
    path = Path(path)
    return path.with_name(path.name + BACKUP_SUFFIX)


def check_file(
    path: str | Path, full: bool = False, limit: int = MAX_PROBLEMS,
    db: sqlite3.Connection | None = None,
) -> list[str]:
    """What is wrong with an existing SQLite file, at most `limit` lines; [] when nothing is.

    Its header and size first (a file cut short by less than a page passes SQLite's own checks),
    then `PRAGMA quick_check` (O(file), no index cross-check) or, `full`, `integrity_check`, on
    `db` (the store's own connection, before it writes anything) or a read-only connection:
    nothing is written to the file. OSError if it cannot be read.
    """
    path = Path(path)
    problem, readable = _header_problem(path)
    found = [] if problem is None else [problem]
    if found and not (full and readable):
        return found  # the full check goes on to list what SQLite finds in a short file
    return (found + _pragma_check(path, full, limit, db))[:limit]


def _pragma_check(
    path: Path, full: bool, limit: int, db: sqlite3.Connection | None
) -> list[str]:
    """SQLite's own check of the file's pages: the lines of what is wrong ([] if nothing)."""
    pragma = "integrity_check" if full else "quick_check"
    own = db is None
    if db is None:
        uri = path.absolute().as_uri() + "?mode=ro"
        try:
            db = sqlite3.connect(uri, uri=True, isolation_level=None, check_same_thread=False)
        except sqlite3.Error as exc:
            raise OSError(f"cannot read {path}: {exc}") from None
    try:
        rows = [str(r[0]) for r in db.execute(f"PRAGMA {pragma}({limit})")]
    except sqlite3.OperationalError as exc:  # locked, unreadable: not a verdict on the file
        raise OSError(f"cannot check {path}: {exc}") from None
    except sqlite3.DatabaseError as exc:  # malformed, not a database: the check itself broke
        return [f"SQLite cannot read it: {exc}"]
    finally:
        if own:
            db.close()
    lines = [ln for r in rows for ln in r.splitlines() if ln and not ln.startswith("*** in ")]
    return [ln for ln in lines if ln != "ok"]


def _open_store_problems(path: Path, db: sqlite3.Connection) -> list[str]:
    """What is wrong with a store this process has open on `db` (`check_file`'s quick check).

    Its size is compared with the page count SQLite reads from its header (`os.stat`, no second
    descriptor), then `quick_check` runs on `db` itself.
    """
    size = path.stat().st_size
    short = "the file was cut short"
    try:
        db.execute("PRAGMA schema_version").fetchone()  # reads the header: a database at all?
        (page,) = db.execute("PRAGMA page_size").fetchone()
    except sqlite3.DatabaseError as exc:
        if "not a database" in str(exc):
            return [f"not a SQLite database ({exc}; {size} bytes)"]
        return [f"SQLite cannot read it ({exc}): {short}, or its pages overwritten"]
    if size % page:
        return [f"{size} bytes is not a whole number of {page}-byte pages: {short}"]
    try:
        (pages,) = db.execute("PRAGMA page_count").fetchone()
    except sqlite3.DatabaseError as exc:  # fewer pages than its header says, or pages damaged
        return [f"SQLite cannot read it ({exc}): {short}, or its pages overwritten"]
    wal = path.with_name(path.name + "-wal")
    settled = not wal.exists() or wal.stat().st_size == 0  # else the WAL holds newer pages
    if settled and size // page < pages:
        return [f"it holds {size // page} pages, its header says {pages}: {short}"]
    return _pragma_check(path, False, MAX_PROBLEMS, db)


def _header_problem(path: Path) -> tuple[str | None, bool]:
    """A SQLite file's header and size checked against each other.

    (the problem or None, whether SQLite can still read the file: its header is SQLite's).
    It opens the file: never for a file a SQLite connection of this process has open (the
    close would drop that connection's locks; `_open_store_problems` is for those).
    """
    size = path.stat().st_size
    with path.open("rb") as f:
        head = f.read(100)
    if len(head) < 100 or not head.startswith(SQLITE_MAGIC):
        return f"not a SQLite database (no SQLite header; {size} bytes)", False
    (page,) = struct.unpack(">H", head[16:18])
    page = 65536 if page == 1 else page
    if page < 512 or page & (page - 1):
        return f"its header's page size {page} is not a power of two in [512, 65536]", False
    short = "the file was cut short"
    if size % page:
        return f"{size} bytes is not a whole number of {page}-byte pages: {short}", True
    (counter,), (pages,), (valid_for,) = (
        struct.unpack(">I", head[at : at + 4]) for at in (24, 28, 92)
    )
    wal = path.with_name(path.name + "-wal")
    settled = not wal.exists() or wal.stat().st_size == 0  # else the WAL holds newer pages
    if settled and pages and counter == valid_for and size // page < pages:
        return f"it holds {size // page} pages, its header says {pages}: {short}", True
    return None, True


def refusal(path: Path, problems: Sequence[str]) -> str:
    """The one line that refuses a damaged store: which file, what is wrong, what to do."""
    backup = backup_path(path)
    what = f"{path} is damaged ({problems[0]}); refused, nothing written to it"
    check = f"`nod store check --db {path}` lists what is wrong"
    if backup.is_file():
        return (f"{what}: restore its backup — move it (and any {path.name}-wal, -shm) aside "
                f"and copy {backup} in its place; {check}")
    return f"{what}; it has no backup ({backup}): {check}; restore it from a copy of your own"


# A Sample's fields in the samples table's order (after session and trial), read in C.
# `detected`, a bool, binds as the integer 0 or 1.
sample_row: Callable[[Sample], tuple[Any, ...]] = attrgetter(*(f.name for f in fields(Sample)))


class Store:
    """A session database file."""

    def __init__(self, path: str | Path) -> None:
        """Open (or create) a session database; StoreError says why it cannot be used.

        An existing file is checked before anything is written to it (`check_file`, quick):
        a damaged one is refused with DamagedStoreError, the file left as it was.
        """
        self.path = Path(path)
        self._writer = threading.RLock()  # held by the thread whose transaction is open
        self._depth = 0  # how deep that thread's transactions are nested
        try:
            existing = self.path.is_file() and self.path.stat().st_size > 0
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
        except (OSError, sqlite3.Error) as exc:
            raise StoreError(f"cannot open the session database {self.path}: {exc}") from None
        if existing:
            # Checked through this connection, before it writes anything, and never by opening
            # the file a second time: closing any other descriptor of it drops every POSIX lock
            # this process holds on it (SQLite's among them), and a writer elsewhere then took
            # itself for the last one, deleted its WAL, and another connection of this process
            # went on reading a stale WAL index (a crashed conductor's session vanished).
            try:
                problems = _open_store_problems(self.path, self.db)
            except OSError as exc:
                self.db.close()
                raise StoreError(f"cannot open the session database {self.path}: {exc}") from None
            if problems:
                self.db.close()
                raise DamagedStoreError(refusal(self.path, problems))
        try:
            self.db.execute("PRAGMA journal_mode=WAL")
            self.db.execute("PRAGMA synchronous=NORMAL")
            self.db.execute("PRAGMA foreign_keys=ON")
            self.db.executescript(SCHEMA + FITS_SCHEMA + POLICY_SCHEMA)
            self._migrate()
        except sqlite3.DatabaseError as exc:
            self.db.close()
            raise StoreError(
                f"{self.path} is not a usable session database ({exc}); give another --db"
            ) from None

    @contextmanager
    def transaction(self) -> Iterator[None]:
        """One transaction around the writes inside: all of them are stored, or none.

        Every write of the store runs in one. Nested on the same thread, the inner one joins the
        outer (a simulated session's rows, written trial by trial, go in one commit: a cohort
        commits once per participant, not ten times, and never leaves half a session). Another
        thread's write waits for the open transaction to end, rather than failing to begin its
        own on the shared connection (and rolling the open one back as it failed).
        """
        with self._writer:
            if self._depth:
                self._depth += 1
                try:
                    yield
                finally:
                    self._depth -= 1
                return
            with self.db:  # commits at the end, rolls back on an exception
                self.db.execute("BEGIN")
                self._depth = 1
                try:
                    yield
                finally:
                    self._depth = 0

    def _migrate(self) -> None:
        """Bring a file written by an older version up to this schema (columns added at the end)."""
        for table, column, decl in (
            ("trials", "interrupted", "INTEGER NOT NULL DEFAULT 0"),
            ("trials", "attempts", "INTEGER NOT NULL DEFAULT 1"),
            ("samples", "theta", "REAL"),
            ("samples", "distance", "REAL"),
            ("samples", "landmarks", "BLOB"),
            ("fits", "probability", "REAL"),
            ("fits", "prior_p", "REAL"),
            ("withdrawals", "withdrawn_by", "TEXT NOT NULL DEFAULT ''"),
            ("withdrawals", "aggregated", "INTEGER NOT NULL DEFAULT 0"),
            ("policy_cohorts", "policy_text", "TEXT"),
            ("policy_cohorts", "built_on", "TEXT"),
        ):
            have = {row[1] for row in self.db.execute(f"PRAGMA table_info({table})")}
            if column not in have:
                self.db.execute(f"ALTER TABLE {table} ADD COLUMN {column} {decl}")
        if self.db.execute("PRAGMA user_version").fetchone()[0] < STORE_VERSION:
            self._one_trials_table()

    def _one_trials_table(self) -> None:
        """Version 2: every session's trials in `trials` by option name, its option set stored.

        A store of an older version checked its trials' options against red and blue and kept
        the trials of three or more options apart (`option_trials`, by box index). Rebuilt in one
        transaction (SQLite cannot change a CHECK in place): the paper's rows as they were, the
        others with each index replaced by its option's name, and every session without an
        option set given the paper's (red, blue). A crash part-way leaves the old store whole.
        """
        with self.db:
            self.db.execute("BEGIN IMMEDIATE")  # one migrator: a second one waits, then sees 2
            if self.db.execute("PRAGMA user_version").fetchone()[0] >= STORE_VERSION:
                return
            (ddl,) = self.db.execute(
                "SELECT sql FROM sqlite_master WHERE type = 'table' AND name = 'trials'"
            ).fetchone()
            if "IN ('red', 'blue')" in ddl:
                cols = ", ".join(r[1] for r in self.db.execute("PRAGMA table_info(trials)"))
                new = SCHEMA[SCHEMA.index("CREATE TABLE IF NOT EXISTS trials ("):]
                new = new[: new.index(");") + 2].replace(" trials (", " trials_by_name (", 1)
                self.db.execute(new)
                self.db.execute(
                    f"INSERT INTO trials_by_name ({cols}) SELECT {cols} FROM trials"
                )
                self.db.execute("DROP TABLE trials")
                self.db.execute("ALTER TABLE trials_by_name RENAME TO trials")
            tables = {r[0] for r in self.db.execute(
                "SELECT name FROM sqlite_master WHERE type = 'table'")}
            if "option_trials" in tables:
                names = {s: json.loads(n) for s, n in self.db.execute(
                    "SELECT session, names FROM option_sets")}
                cur = self.db.execute("SELECT * FROM option_trials")
                header = [c[0] for c in cur.description]
                for row in cur.fetchall():
                    rec = dict(zip(header, row, strict=True))
                    for field in ("option", "human", "robot"):
                        if rec[field] is None:
                            continue
                        known = names.get(rec["session"], [])
                        if not 0 <= rec[field] < len(known):  # the whole migration is undone
                            raise sqlite3.DatabaseError(
                                f"option_trials: session {rec['session']} trial {rec['trial']}"
                                f" has {field} {rec[field]}, not a box of its option set"
                            )
                        rec[field] = known[rec[field]]
                    self.db.execute(
                        f"INSERT INTO trials ({', '.join(header)}) "
                        f"VALUES ({', '.join('?' * len(header))})",
                        tuple(rec.values()),
                    )
                self.db.execute("DROP TABLE option_trials")
            self.db.execute(
                "INSERT INTO option_sets SELECT session, 2, ? FROM sessions "
                "WHERE session NOT IN (SELECT session FROM option_sets)",
                (json.dumps(list(COLOURS)),),
            )
            self.db.execute(f"PRAGMA user_version = {STORE_VERSION}")

    @classmethod
    def existing(cls, path: str | Path) -> Store:
        """Open a database that must already exist (the tools that read or amend a study's).

        A missing file is a StoreError rather than a new, empty store: a mistyped --db should
        not quietly create one.
        """
        if not Path(path).is_file():
            raise StoreError(f"no such database: {path}")
        return cls(path)

    def close(self) -> None:
        """Close the database (checkpointing the WAL)."""
        self.db.close()

    def __enter__(self) -> Store:
        """`with Store(path) as store:` closes it however the block ends."""
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def backup(self) -> Path:
        """Copy the store as it is now to `<db>.backup` (the last one only); its path.

        SQLite's online backup (a consistent copy while others read or write) into a temp file
        beside it, made a plain rollback-journal file, checked (`quick_check`), synced, then
        renamed over the previous backup: a copy that is torn or damaged never replaces the
        last good one (StoreError, and the temp file removed).
        """
        target = backup_path(self.path)
        tmp = target.with_name(target.name + ".tmp")
        try:
            for leftover in (tmp, *(tmp.with_name(tmp.name + s) for s in ("-journal", "-wal"))):
                leftover.unlink(missing_ok=True)
            copy = sqlite3.connect(tmp, isolation_level=None)
            try:
                self.db.backup(copy)
                copy.execute("PRAGMA journal_mode=DELETE")  # one self-contained file
            finally:
                copy.close()
            problems = check_file(tmp)
            if problems:
                raise StoreError(
                    f"the backup of {self.path} fails its check ({problems[0]}): not kept; "
                    f"{target} is left as it was — run `nod store check --db {self.path}`"
                )
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(tmp, target)
            fd = os.open(target.parent, os.O_RDONLY)  # the rename itself, on disk
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        except (OSError, sqlite3.Error) as exc:
            tmp.unlink(missing_ok=True)
            if isinstance(exc, StoreError):
                raise
            raise StoreError(f"cannot back {self.path} up to {target}: {exc}") from None
        return target

    def interrupted_sessions(self) -> list[tuple[str, int]]:
        """Sessions left 'running' by a crash, with how many trials they completed."""
        rows = self.db.execute(
            "SELECT s.session, COUNT(t.trial) FROM sessions s LEFT JOIN trials t "
            "ON t.session = s.session WHERE s.status = 'running' GROUP BY s.session"
        )
        return [(str(a), int(b)) for a, b in rows]

    def begin_session(
        self,
        session: str,
        participant: str,
        rig: str,
        seed: int | None,
        started_ns: int,
        config: dict[str, Any],
        options: Sequence[str] = COLOURS,
    ) -> None:
        """Record a new session as running, with its option set (default: the paper's)."""
        names = tuple(options)
        if len(names) < 2 or len(set(names)) != len(names) or not all(names):
            raise ValueError(f"an option set is two or more distinct names, got {list(names)}")
        with self.transaction():
            self.db.execute(
                "INSERT INTO sessions VALUES (?, ?, ?, ?, ?, NULL, 'running', ?)",
                (session, participant, rig, seed, started_ns, json.dumps(config, default=str)),
            )
            self.db.execute(
                "INSERT INTO option_sets VALUES (?, ?, ?)",
                (session, len(names), json.dumps(list(names))),
            )

    def option_names(self, session: str) -> tuple[str, ...]:
        """The option set a session ran (box j is `names[j]`); the paper's for an unknown one."""
        row = self.db.execute(
            "SELECT names FROM option_sets WHERE session = ?", (session,)
        ).fetchone()
        return COLOURS if row is None else tuple(json.loads(row[0]))

    def resume_session(self, session: str) -> tuple[str, int | None, int]:
        """Mark a stored session running again; (participant, seed, trials stored so far).

        StoreError if there is no such session. The trials of a session are stored in order,
        one transaction each, so the next trial to run is the count plus one.
        """
        row = self.db.execute(
            "SELECT participant, seed FROM sessions WHERE session = ?", (session,)
        ).fetchone()
        if row is None:
            known = [r[0] for r in self.db.execute("SELECT session FROM sessions")]
            raise StoreError(f"no session {session!r} in {self.path}; known: {known[-5:]}")
        (done,) = self.db.execute(
            "SELECT COALESCE(MAX(trial), 0) FROM trials WHERE session = ?", (session,)
        ).fetchone()
        with self.transaction():
            self.db.execute(
                "UPDATE sessions SET status = 'running', finished_ns = NULL WHERE session = ?",
                (session,),
            )
        return str(row[0]), row[1], int(done)

    def finish_session(self, session: str, finished_ns: int, status: str = "complete") -> None:
        """Mark a session complete (or aborted)."""
        with self.transaction():
            self.db.execute(
                "UPDATE sessions SET finished_ns = ?, status = ? WHERE session = ?",
                (finished_ns, status, session),
            )

    def begin_attempt(self, session: str, trial: int, attempt: int, t_start_ns: int) -> None:
        """A trial's attempt has started (committed at once: a crash leaves it on record)."""
        with self.transaction():
            self.db.execute(
                "INSERT OR REPLACE INTO open_attempts VALUES (?, ?, ?, ?)",
                (session, trial, attempt, t_start_ns),
            )

    def open_attempt(self, session: str) -> tuple[int, int, int] | None:
        """The attempt a crash left open, as (trial, attempt, t_start_ns), or None."""
        row = self.db.execute(
            "SELECT trial, attempt, t_start_ns FROM open_attempts WHERE session = ?", (session,)
        ).fetchone()
        return None if row is None else (int(row[0]), int(row[1]), int(row[2]))

    def attempts_made(self, session: str, trial: int) -> int:
        """How many starts of a trial were interrupted and stored so far (0: none)."""
        (n,) = self.db.execute(
            "SELECT COALESCE(MAX(attempt), 0) FROM interruptions WHERE session = ? AND trial = ?",
            (session, trial),
        ).fetchone()
        return int(n)

    def _close_attempt(self, session: str, trial: int) -> None:
        self.db.execute(
            "DELETE FROM open_attempts WHERE session = ? AND trial = ?", (session, trial)
        )

    def write_trial(
        self,
        session: str,
        rec: TrialRecord,
        samples: Iterable[Sample],
        events: Iterable[SafetyEvent | RigEventRecord] = (),
        cues: Iterable[CueRecord] = (),
    ) -> None:
        """Store one trial, its samples and cues, and the events since the last write, at once.

        ValueError if its option, human or robot is not a name of the session's option set.
        """
        self.write_trial_rows(session, rec, map(sample_row, samples), events, cues)

    def write_trial_rows(
        self,
        session: str,
        rec: TrialRecord,
        rows: Iterable[tuple[Any, ...]],
        events: Iterable[SafetyEvent | RigEventRecord] = (),
        cues: Iterable[CueRecord] = (),
    ) -> None:
        """`write_trial` with its samples as rows: each a Sample's fields in order (`sample_row`).

        For a writer that has the values already (a simulated cohort stores ~2,000 samples per
        participant, and building each as a Sample to read it back cost it a tenth of its time).
        """
        names = self.option_names(session)
        for field in ("option", "human", "robot"):
            value = getattr(rec, field)
            if value is not None and value not in names:
                raise ValueError(
                    f"trial {rec.trial}: {field} {value!r} is not one of {list(names)}"
                )
        with self.transaction():
            self.db.execute(
                "INSERT OR REPLACE INTO trials VALUES "
                "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (session, *astuple_record(rec)),
            )
            self._events(session, events)
            self._cues(session, cues)
            self._close_attempt(session, rec.trial)
            self.db.execute(
                "DELETE FROM samples WHERE session = ? AND trial = ?", (session, rec.trial)
            )
            trial = rec.trial
            self.db.executemany(
                "INSERT INTO samples VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [(session, trial, *row) for row in rows],
            )

    def write_interruption(
        self,
        session: str,
        rec: Interruption,
        events: Iterable[SafetyEvent | RigEventRecord] = (),
        cues: Iterable[CueRecord] = (),
    ) -> None:
        """Store a broken start of a trial, the events that broke it and its cues atomically."""
        with self.transaction():
            self.db.execute(
                "INSERT OR REPLACE INTO interruptions VALUES (?, ?, ?, ?, ?, ?)",
                (session, *astuple_record(rec)),
            )
            self._events(session, events)
            self._cues(session, cues)
            self._close_attempt(session, rec.trial)

    def write_events(
        self, session: str, events: Iterable[SafetyEvent | RigEventRecord]
    ) -> None:
        """Store safety events on their own (those after the last trial of a session)."""
        with self.transaction():
            self._events(session, events)

    def _events(self, session: str, events: Iterable[SafetyEvent | RigEventRecord]) -> None:
        events = list(events)
        self.db.executemany(
            "INSERT INTO safety_events VALUES (?, ?, ?, ?, ?, ?, ?)",
            [(session, *astuple_record(e)) for e in events if isinstance(e, SafetyEvent)],
        )
        self.db.executemany(
            "INSERT INTO rig_events VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            [(session, *astuple_record(e)) for e in events if isinstance(e, RigEventRecord)],
        )

    def _cues(self, session: str, cues: Iterable[CueRecord]) -> None:
        self.db.executemany(
            "INSERT INTO cues VALUES (?, ?, ?, ?, ?, ?)",
            [(session, *astuple_record(c)) for c in cues],
        )

    def rig_events(self, session: str) -> list[RigEventRecord]:
        """A session's launcher events (restarts and the like) in time order."""
        return session_rows.rig_events(self.db, session)

    def safety_events(self, session: str) -> list[SafetyEvent]:
        """A session's safety events in time order."""
        return session_rows.safety_events(self.db, session)

    def interruptions(self, session: str) -> list[Interruption]:
        """A session's broken trial starts, in order."""
        return session_rows.interruptions(self.db, session)

    def sessions(self) -> list[dict[str, Any]]:
        """Every session, oldest first."""
        cur = self.db.execute("SELECT * FROM sessions ORDER BY started_ns")
        cols = [c[0] for c in cur.description]
        return [dict(zip(cols, row, strict=True)) for row in cur]

    def trials(self, session: str | None = None) -> list[tuple[str, TrialRecord]]:
        """Trials of one session (default: the latest), in order, with their session id."""
        if session is None:
            row = self.db.execute(
                "SELECT session FROM sessions ORDER BY started_ns DESC LIMIT 1"
            ).fetchone()
            if row is None:
                return []
            session = row[0]
        return [(session, t) for t in session_rows.trials(self.db, session)]

    def set_clicks(self, session: str, trial: int, clicks: int | None) -> TrialRecord:
        """Enter (or correct) a stored trial's counter clicks and rescore it; the new record.

        A trial is stored the moment it ends, with its clicks "not entered"; the operator's
        answer comes after (the prompt, or `nod clicks` later) and changes only the clicks and
        the points they earn (`services.model.scoring.trial_points`, with the session's own
        target). StoreError if there is no such trial or it was interrupted (never scored).
        """
        stored = {t.trial: t for _, t in self.trials(session)}.get(trial)
        if stored is None:
            raise StoreError(f"session {session!r} has no stored trial {trial}")
        if stored.interrupted:
            raise StoreError(f"trial {trial} of session {session} was interrupted: never scored")
        if clicks is not None and clicks < 0:
            raise StoreError(f"clicks must be a whole number >= 0, got {clicks}")
        points = trial_points(stored.human, stored.robot, stored.violations, clicks,
                              self.target_clicks(session))
        with self.transaction():
            self.db.execute(
                "UPDATE trials SET clicks = ?, score = ? WHERE session = ? AND trial = ?",
                (clicks, points, session, trial),
            )
        return replace(stored, clicks=clicks, score=points)

    def target_clicks(self, session: str) -> int:
        """The counter target the session ran with (its stored protocol; 10 if not stored)."""
        row = self.db.execute("SELECT config FROM sessions WHERE session = ?", (session,))
        found = row.fetchone()
        try:
            target = json.loads(found[0])["protocol"]["target_clicks"] if found else 10
        except (TypeError, KeyError, ValueError):
            return 10
        return target if isinstance(target, int) and target > 0 else 10

    def write_questionnaires(
        self,
        records: Sequence[QuestionnaireRecord],
        entered_ns: int,
        source: str,
        replace: bool = False,
    ) -> None:
        """Store questionnaire answers all or nothing, in one transaction.

        Without `replace`, a participant who already has answers is an error (ValueError naming
        them) and nothing is written; with it, their earlier answers are overwritten.
        """
        ids = [r.participant for r in records]
        if len(set(ids)) != len(ids):
            dup = sorted({p for p in ids if ids.count(p) > 1})
            raise ValueError(f"participant(s) given more than once: {', '.join(dup)}")
        with self.transaction():
            if not replace and ids:
                marks = ", ".join("?" * len(ids))
                taken = [
                    str(row[0])
                    for row in self.db.execute(
                        f"SELECT participant FROM questionnaires WHERE participant IN ({marks}) "
                        "ORDER BY participant",
                        ids,
                    )
                ]
                if taken:
                    raise ValueError(
                        f"answers already stored for {', '.join(taken)}; pass --replace to "
                        "overwrite them"
                    )
            self.db.executemany(
                "INSERT OR REPLACE INTO questionnaires VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                [(*astuple_record(r), entered_ns, source) for r in records],
            )

    def write_questionnaire(
        self, record: QuestionnaireRecord, entered_ns: int, source: str, replace: bool = False
    ) -> None:
        """Store one participant's answers (see write_questionnaires)."""
        self.write_questionnaires([record], entered_ns, source, replace)

    def questionnaires(self) -> list[QuestionnaireRecord]:
        """Every participant's answers, ordered by participant id."""
        cur = self.db.execute(
            "SELECT participant, q1, q2, q3, q4, q5 FROM questionnaires ORDER BY participant"
        )
        return [QuestionnaireRecord(*row) for row in cur]

    def add_recording(self, session: str, path: str | Path, started_ns: int) -> None:
        """Link a recording (an MCAP file) to a stored session; the path is stored absolute."""
        with self.transaction():
            self.db.execute(
                "INSERT OR REPLACE INTO recordings VALUES (?, ?, ?)",
                (session, str(Path(path).resolve()), started_ns),
            )

    def recordings(self, session: str) -> list[tuple[str, int]]:
        """A session's recordings as (path, started_ns), oldest first."""
        cur = self.db.execute(
            "SELECT path, started_ns FROM recordings WHERE session = ? ORDER BY started_ns, path",
            (session,),
        )
        return [(str(p), int(t)) for p, t in cur]

    def samples(self, session: str, trial: int) -> Sequence[Sample]:
        """A trial's samples in time order."""
        cur = self.db.execute(
            "SELECT t_ns, detected, hand_x, hand_y, z_h, z_r, b_r, ee_x, ee_y, theta, distance, "
            "landmarks FROM samples "
            "WHERE session = ? AND trial = ? ORDER BY t_ns",
            (session, trial),
        )
        return [Sample(r[0], bool(r[1]), *r[2:]) for r in cur]


def back_up(store: Store) -> Path | None:
    """Back the store up as a session ends (`Store.backup`); a failure is logged, not raised."""
    try:
        path = store.backup()
    except StoreError as exc:
        log.error("no backup of the store: %s", exc)
        return None
    log.info("store backed up to %s", path)
    return path


def astuple_record(rec: Any) -> tuple[Any, ...]:
    """A record (a flat dataclass) as a row tuple, in column order; its values, not copies."""
    return tuple(getattr(rec, f.name) for f in fields(rec))
