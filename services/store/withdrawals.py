"""Participants who withdrew: table `withdrawals`, and the one rule every reader of a study applies.

**Withdrawn is not the same as consent refused.** A refusal (`consent = 0` in `participants`,
`nod study consent … --no` before anything was recorded) only stops a session from starting:
there is nothing of theirs to leave out. A *withdrawal* is a participant taking back consent
they had given — after `consent --yes`, or once a session, answers or a fit of theirs is
stored — and it is a row here: who, when, and why (optional, non-identifying). `nod study
withdraw` writes it, and `nod study consent … --no` writes it too when the participant had
consented or has data. A withdrawn participant's consent row (if kept) says 0; the row here
is what takes their data out of the study.

From then on every reader leaves them out unless told `--include-withdrawn`: `nod export`,
`nod analyze study` and `nod fit` select through `withdrawn_filter` (one place), and each says
so in one line (`WithdrawnFilter.note`: "left out (withdrawn): P02"). `nod study status` shows
them withdrawn with no resume line, `nod study start`/`next` never pick them, their id is never
given to anyone else (`participants.next_free_ids`), and `nod experiment` refuses them
(`withdrawal_problem`).

**Deleting their data** (`delete_participant`: `nod study withdraw --delete`, or the study's
`on_withdrawal = "delete"`) removes, in one transaction, every row of every table keyed by their
participant id or by one of their sessions — sessions, trials, samples, interruptions, safety
and rig events, cues, open attempts, recordings, orders, questionnaires, consent and
demographics, fits, the N-option tables, and any table added later with a `participant` or
`session` column — with SQLite's `secure_delete` on (freed pages are zeroed), then their
recordings' MCAP files (a file another participant's session also points at is kept), then
refreshes the store's `<db>.backup` if it has one. The withdrawal row stays, with `deleted = 1`,
when, by whom (`withdrawn_by`: the operator's user@host), and the rows deleted per table
(`counts`, JSON); its reason is cleared: nothing personal is left but the pseudonymous id, which
keeps the id from being reused.

**An anonymous aggregate** (`aggregate = True`: `--aggregate`, or the study's `on_withdrawal =
"aggregate"`): before their rows go, in the same transaction, each of their stored trials adds
one to `withdrawn_aggregates` (option set, trial, mode, outcome — 'none' for a timeout or an
interrupted trial — and a count n), the study's counts over every participant withdrawn this
way: no id, no session, no time. The withdrawal row says `aggregated = 1` and counts the trials
(`aggregate_trials`). `nod export` writes the table as withdrawn_aggregates.csv.
"""

from __future__ import annotations

import contextlib
import getpass
import json
import logging
import socket
import sqlite3
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from services.model.geometry import COLOURS
from services.store.store import Store, StoreError, backup_path

log = logging.getLogger("nod.store")

INCLUDE_FLAG = "--include-withdrawn"
Row = TypeVar("Row", bound=Mapping[str, Any])


@dataclass(frozen=True, slots=True)
class Withdrawal:
    """One participant's withdrawal, as stored."""

    participant: str
    withdrawn_ns: int  # wall clock, when it was recorded
    reason: str  # '' when none was given, or once their data is deleted
    deleted: bool  # their data was deleted (the counts say what)
    deleted_ns: int | None
    counts: dict[str, int] = field(default_factory=dict)  # rows deleted per table; files
    by: str = ""  # who recorded it (user@host; '' before this was kept)
    aggregated: bool = False  # their trials' outcomes were added to `withdrawn_aggregates`


def operator_id() -> str:
    """Who is withdrawing someone: user@host of this process ('unknown' for an unknown user)."""
    try:
        user = getpass.getuser()
    except (OSError, KeyError):  # no login name and no passwd entry (a bare container)
        user = "unknown"
    return f"{user}@{socket.gethostname()}"


def _db(where: Store | sqlite3.Connection) -> sqlite3.Connection:
    return where.db if isinstance(where, Store) else where


def _has_table(db: sqlite3.Connection, name: str) -> bool:
    row = db.execute(
        "SELECT 1 FROM sqlite_master WHERE name = ? UNION SELECT 1 FROM sqlite_temp_master "
        "WHERE name = ?", (name, name)
    ).fetchone()
    return row is not None


def withdrawals(where: Store | sqlite3.Connection) -> dict[str, Withdrawal]:
    """Every withdrawal, by participant: of a store, or of `nod export`'s union of stores."""
    db = _db(where)
    if not _has_table(db, "withdrawals"):  # a bare connection on a file no Store opened
        return {}
    rows = db.execute(
        "SELECT participant, withdrawn_ns, reason, deleted, deleted_ns, counts, withdrawn_by, "
        "aggregated FROM withdrawals ORDER BY participant"
    )
    return {
        str(p): Withdrawal(str(p), int(t), str(r), bool(d), None if dt is None else int(dt),
                           json.loads(c or "{}"), str(by or ""), bool(agg))
        for p, t, r, d, dt, c, by, agg in rows
    }


def withdrawn(where: Store | sqlite3.Connection) -> set[str]:
    """The participants who withdrew."""
    return set(withdrawals(where))


@dataclass(frozen=True, slots=True)
class WithdrawnFilter:
    """Which participants a reader leaves out as withdrawn, and the one line that says so."""

    withdrawn: Mapping[str, bool]  # participant -> their data was deleted
    include: bool = False  # --include-withdrawn: keep them (what is left of them)

    def keeps(self, participant: str) -> bool:
        """Whether this participant's rows are read."""
        return self.include or participant not in self.withdrawn

    def sessions(self, rows: Iterable[Row]) -> list[Row]:
        """The session rows (with a `participant`) of the participants kept."""
        return [r for r in rows if self.keeps(str(r["participant"]))]

    @property
    def left_out(self) -> list[str]:
        """The withdrawn participants left out, sorted ([] with --include-withdrawn)."""
        return [] if self.include else sorted(self.withdrawn)

    def note(self) -> str | None:
        """One line naming the withdrawn participants and what was done with them, or None."""
        if not self.withdrawn:
            return None
        names = ", ".join(p + (" (deleted)" if self.withdrawn[p] else "")
                          for p in sorted(self.withdrawn))
        if self.include:
            return f"included although withdrawn ({INCLUDE_FLAG}): {names}"
        return f"left out (withdrawn): {names}; {INCLUDE_FLAG} keeps them"


def withdrawn_filter(
    where: Store | sqlite3.Connection | Iterable[Store | sqlite3.Connection],
    include: bool = False,
) -> WithdrawnFilter:
    """The withdrawn participants of one store (or connection), or of several, as one filter."""
    sources = [where] if isinstance(where, Store | sqlite3.Connection) else list(where)
    found: dict[str, bool] = {}
    for source in sources:
        for w in withdrawals(source).values():
            found[w.participant] = found.get(w.participant, False) or w.deleted
    return WithdrawnFilter(found, include)


def withdrawal_problem(store: Store, participant: str) -> str | None:
    """Why a withdrawn participant may not run (a new session or a resumed one), or None."""
    w = withdrawals(store).get(participant)
    if w is None:
        return None
    from datetime import datetime

    when = datetime.fromtimestamp(w.withdrawn_ns / 1e9).isoformat(timespec="seconds")
    return (f"participant {participant} withdrew from the study ({when}): no session of theirs "
            "runs again; a new person gets a new id")


def record_withdrawal(
    store: Store, participant: str, t_ns: int, reason: str = "", by: str = ""
) -> Withdrawal:
    """Record a withdrawal (a second one keeps the first's time, reason and operator); the row."""
    with store.transaction():
        store.db.execute(
            "INSERT OR IGNORE INTO withdrawals (participant, withdrawn_ns, reason, withdrawn_by) "
            "VALUES (?, ?, ?, ?)",
            (participant, t_ns, reason.strip(), by),
        )
    log.info("participant %s withdrawn", participant)
    return withdrawals(store)[participant]


def _tables(db: sqlite3.Connection) -> list[tuple[str, set[str]]]:
    """Every table but `withdrawals` with its columns."""
    names = [str(r[0]) for r in db.execute(
        "SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%' "
        "AND name != 'withdrawals' ORDER BY name")]
    return [(n, {str(c[1]) for c in db.execute(f'PRAGMA table_info("{n}")')}) for n in names]


def _sessions_of(db: sqlite3.Connection, participant: str) -> list[str]:
    found = {str(r[0]) for r in db.execute(
        "SELECT session FROM sessions WHERE participant = ? "
        "UNION SELECT session FROM session_orders WHERE participant = ?",
        (participant, participant))}
    return sorted(found)


def personal_rows(store: Store, participant: str) -> dict[str, int]:
    """How many rows of each table are this participant's (what `delete_participant` removes)."""
    db = store.db
    sessions = _sessions_of(db, participant)
    counts: dict[str, int] = {}
    for table, cols in _tables(db):
        n = 0
        if "participant" in cols:
            n += db.execute(f'SELECT COUNT(*) FROM "{table}" WHERE participant = ?',
                            (participant,)).fetchone()[0]
        if "session" in cols:
            extra = " AND participant != ?" if "participant" in cols else ""
            for s in sessions:
                args = (s, participant) if extra else (s,)
                n += db.execute(f'SELECT COUNT(*) FROM "{table}" WHERE session = ?{extra}',
                                args).fetchone()[0]
        if n:
            counts[table] = n
    return counts


def recording_files(store: Store, participant: str) -> tuple[list[Path], list[Path]]:
    """Their recordings' files: (those only they use, those another's session points at too)."""
    db = store.db
    sessions = set(_sessions_of(db, participant))
    theirs: set[str] = set()
    shared: set[str] = set()
    for session, path in db.execute("SELECT session, path FROM recordings"):
        (theirs if session in sessions else shared).add(str(path))
    return sorted(map(Path, theirs - shared)), sorted(map(Path, theirs & shared))


@dataclass(frozen=True, slots=True)
class Deletion:
    """What `delete_participant` did."""

    withdrawal: Withdrawal
    removed: list[Path]  # recording files deleted
    kept: list[Path]  # recording files another participant's session points at too
    missing: list[Path]  # recording files already gone
    failed: list[tuple[Path, str]]  # recording files that could not be deleted, and why
    backup: Path | None  # the store's backup, rewritten without them (None: it has none)
    backup_error: str | None = None


def _aggregate(db: sqlite3.Connection, sessions: list[str]) -> int:
    """Add the sessions' trials to `withdrawn_aggregates` (module doc); how many trials."""
    marks = ", ".join("?" * len(sessions))
    rows = db.execute(
        "SELECT COALESCE(o.names, ?), t.trial, t.mode, COALESCE(t.outcome, 'none'), COUNT(*) "
        f"FROM trials t LEFT JOIN option_sets o ON o.session = t.session "
        f"WHERE t.session IN ({marks}) GROUP BY 1, 2, 3, 4",
        (json.dumps(list(COLOURS)), *sessions),
    ).fetchall()
    db.executemany(
        "INSERT INTO withdrawn_aggregates VALUES (?, ?, ?, ?, ?) ON CONFLICT "
        "(options, trial, mode, outcome) DO UPDATE SET n = n + excluded.n", rows)
    return sum(int(r[4]) for r in rows)


def delete_participant(
    store: Store, participant: str, t_ns: int, by: str = "", aggregate: bool = False
) -> Deletion:
    """Withdraw a participant and delete every row and recording file of theirs (module doc).

    The rows go in one transaction (the withdrawal row with its counts in the same one, and
    with `aggregate` their trials' outcomes added to the anonymous counts first); the files
    after it commits; a file that cannot be removed is reported, not raised.
    """
    db = store.db
    files, kept = recording_files(store, participant)
    sessions = _sessions_of(db, participant)
    db.execute("PRAGMA secure_delete = ON")
    try:
        with db:
            db.execute("BEGIN IMMEDIATE")
            db.execute("PRAGMA defer_foreign_keys = ON")  # children and parents, any order
            counts: dict[str, int] = {}
            if aggregate:
                counts["aggregate_trials"] = _aggregate(db, sessions)
            for table, cols in _tables(db):
                n = 0
                if "participant" in cols:
                    n += db.execute(f'DELETE FROM "{table}" WHERE participant = ?',
                                    (participant,)).rowcount
                if "session" in cols:
                    for s in sessions:
                        n += db.execute(f'DELETE FROM "{table}" WHERE session = ?', (s,)).rowcount
                if n:
                    counts[table] = n
            counts["recording_files"] = len(files)
            db.execute(
                "INSERT INTO withdrawals (participant, withdrawn_ns, reason, deleted, deleted_ns, "
                "counts, withdrawn_by, aggregated) VALUES (?, ?, '', 1, ?, ?, ?, ?) "
                "ON CONFLICT (participant) DO UPDATE SET reason = '', deleted = 1, "
                "deleted_ns = excluded.deleted_ns, counts = excluded.counts, "
                "aggregated = excluded.aggregated, withdrawn_by = CASE WHEN withdrawn_by = '' "
                "THEN excluded.withdrawn_by ELSE withdrawn_by END",
                (participant, t_ns, t_ns, json.dumps(counts, sort_keys=True), by,
                 int(aggregate)),
            )
    finally:
        db.execute("PRAGMA secure_delete = OFF")
    # the deleted pages out of the WAL too (busy readers: it is checkpointed later)
    with contextlib.suppress(sqlite3.Error):
        db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    log.info("participant %s withdrawn and deleted: %s", participant, counts)
    removed: list[Path] = []
    missing: list[Path] = []
    failed: list[tuple[Path, str]] = []
    for path in files:
        try:
            path.unlink()
            removed.append(path)
        except FileNotFoundError:
            missing.append(path)
        except OSError as exc:
            failed.append((path, exc.strerror or str(exc)))
    backup: Path | None = None
    error = None
    if backup_path(store.path).is_file():
        try:
            backup = store.backup()
        except StoreError as exc:
            error = str(exc)
    return Deletion(withdrawals(store)[participant], removed, kept, missing, failed, backup, error)
