"""The session store: one SQLite file (WAL) with sessions, trials and decimated samples.

Each trial is written in one transaction together with its samples, so a crash mid-trial loses
at most that trial's unfinished samples; a session left 'running' is reported when the store is
opened again.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

SCHEMA = """
CREATE TABLE IF NOT EXISTS sessions (
    session     TEXT PRIMARY KEY,
    participant TEXT NOT NULL,
    rig         TEXT NOT NULL,
    seed        INTEGER,
    started_ns  INTEGER NOT NULL,
    finished_ns INTEGER,
    status      TEXT NOT NULL CHECK (status IN ('running', 'complete', 'aborted')),
    config      TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS trials (
    session     TEXT NOT NULL REFERENCES sessions(session),
    trial       INTEGER NOT NULL,
    mode        TEXT NOT NULL CHECK (mode IN ('dissensus', 'consensus')),
    option      TEXT CHECK (option IN ('red', 'blue')),
    gaze_level  TEXT NOT NULL,
    yaw         REAL NOT NULL,
    pitch       REAL NOT NULL,
    t_go_ns     INTEGER,
    t_end_ns    INTEGER,
    human       TEXT CHECK (human IN ('red', 'blue')),
    robot       TEXT CHECK (robot IN ('red', 'blue')),
    outcome     TEXT CHECK (outcome IN ('C', 'CH', 'D', 'DH')),
    switches    INTEGER NOT NULL,
    violations  INTEGER NOT NULL,
    clicks      INTEGER,
    score       INTEGER NOT NULL,
    end_reason  TEXT NOT NULL,
    PRIMARY KEY (session, trial)
);
CREATE TABLE IF NOT EXISTS samples (
    session  TEXT NOT NULL,
    trial    INTEGER NOT NULL,
    t_ns     INTEGER NOT NULL,
    detected INTEGER NOT NULL,
    hand_x   REAL,
    hand_y   REAL,
    z_h      REAL,
    z_r      REAL,
    b_r      REAL,
    ee_x     REAL,
    ee_y     REAL
);
CREATE INDEX IF NOT EXISTS samples_by_trial ON samples (session, trial, t_ns);
"""


@dataclass(frozen=True, slots=True)
class TrialRecord:
    """One finished trial as stored."""

    trial: int
    mode: str
    option: str | None
    gaze_level: str
    yaw: float
    pitch: float
    t_go_ns: int | None
    t_end_ns: int | None
    human: str | None
    robot: str | None
    outcome: str | None
    switches: int
    violations: int
    clicks: int | None
    score: int
    end_reason: str


@dataclass(frozen=True, slots=True)
class Sample:
    """One decimated sample of a trial's streams."""

    t_ns: int
    detected: bool
    hand_x: float | None
    hand_y: float | None
    z_h: float | None
    z_r: float | None
    b_r: float | None
    ee_x: float | None
    ee_y: float | None


class Store:
    """A session database file."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=NORMAL")
        self.db.execute("PRAGMA foreign_keys=ON")
        self.db.executescript(SCHEMA)

    def close(self) -> None:
        """Close the database (checkpointing the WAL)."""
        self.db.close()

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
    ) -> None:
        """Record a new session as running."""
        with self.db:
            self.db.execute("BEGIN")
            self.db.execute(
                "INSERT INTO sessions VALUES (?, ?, ?, ?, ?, NULL, 'running', ?)",
                (session, participant, rig, seed, started_ns, json.dumps(config, default=str)),
            )

    def finish_session(self, session: str, finished_ns: int, status: str = "complete") -> None:
        """Mark a session complete (or aborted)."""
        with self.db:
            self.db.execute("BEGIN")
            self.db.execute(
                "UPDATE sessions SET finished_ns = ?, status = ? WHERE session = ?",
                (finished_ns, status, session),
            )

    def write_trial(self, session: str, rec: TrialRecord, samples: Iterable[Sample]) -> None:
        """Store one trial and its samples atomically."""
        with self.db:
            self.db.execute("BEGIN")
            self.db.execute(
                "INSERT OR REPLACE INTO trials VALUES "
                "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (session, *astuple_record(rec)),
            )
            self.db.execute(
                "DELETE FROM samples WHERE session = ? AND trial = ?", (session, rec.trial)
            )
            self.db.executemany(
                "INSERT INTO samples VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [
                    (
                        session,
                        rec.trial,
                        s.t_ns,
                        int(s.detected),
                        s.hand_x,
                        s.hand_y,
                        s.z_h,
                        s.z_r,
                        s.b_r,
                        s.ee_x,
                        s.ee_y,
                    )
                    for s in samples
                ],
            )

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
        cur = self.db.execute("SELECT * FROM trials WHERE session = ? ORDER BY trial", (session,))
        return [(r[0], TrialRecord(*r[1:])) for r in cur]

    def samples(self, session: str, trial: int) -> Sequence[Sample]:
        """A trial's samples in time order."""
        cur = self.db.execute(
            "SELECT t_ns, detected, hand_x, hand_y, z_h, z_r, b_r, ee_x, ee_y FROM samples "
            "WHERE session = ? AND trial = ? ORDER BY t_ns",
            (session, trial),
        )
        return [Sample(r[0], bool(r[1]), *r[2:]) for r in cur]


def astuple_record(rec: TrialRecord) -> tuple[Any, ...]:
    """A trial record as a row tuple, in column order."""
    return tuple(asdict(rec).values())
