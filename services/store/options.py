"""N_o-option sessions in the store: the option set of a session and its trials.

A session over three or more options is a row of `sessions` as any other (`Store.begin_session`,
its config, its status), plus its option set in `option_sets` (the names, box j is `names[j]`)
and its trials in `option_trials`, whose option, human and robot are box indices into that
set. The paper's `trials` table keeps its CHECK (option IN ('red', 'blue')) and is untouched: a
two-option store reads exactly as before. The tables are created when first used, so a store
file of an older version gets them then. `nod export` writes them as option_sets.csv and
option_trials.csv (`export_rows`, with each option's name beside its index).
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable
from dataclasses import astuple, dataclass, replace
from typing import Any

from services.store.records import RigEventRecord, SafetyEvent
from services.store.store import Store

OPTIONS_SCHEMA = """
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


@dataclass(frozen=True, slots=True)
class OptionsTrialRecord:
    """One stored N_o-option trial; option, human and robot index the session's option set."""

    trial: int
    mode: str
    option: int | None
    gaze_level: str
    yaw: float
    pitch: float
    t_go_ns: int | None
    t_end_ns: int | None
    human: int | None
    robot: int | None
    outcome: str | None
    switches: int
    violations: int
    clicks: int | None
    score: int
    end_reason: str
    interrupted: int = 0  # broken by a safe stop or an e-stop and not repeated: never scored
    attempts: int = 1  # starts of this trial, the interrupted ones included


class OptionsStore:
    """The N_o-option tables of a `Store`."""

    def __init__(self, store: Store) -> None:
        self.store = store
        self.db = store.db
        self.db.executescript(OPTIONS_SCHEMA)

    def begin_session(
        self, session: str, participant: str, rig: str, seed: int | None, started_ns: int,
        config: dict[str, Any], names: tuple[str, ...],
    ) -> None:
        """Record a new session as running, with its option set."""
        self.store.begin_session(session, participant, rig, seed, started_ns,
                                 {**config, "options": list(names)})
        with self.db:
            self.db.execute("BEGIN")
            self.db.execute("INSERT INTO option_sets VALUES (?, ?, ?)",
                            (session, len(names), json.dumps(list(names))))

    def names(self, session: str) -> tuple[str, ...] | None:
        """The option set of a session (None: a two-option session)."""
        row = self.db.execute(
            "SELECT names FROM option_sets WHERE session = ?", (session,)
        ).fetchone()
        return None if row is None else tuple(json.loads(row[0]))

    def write_trial(
        self, session: str, rec: OptionsTrialRecord,
        events: Iterable[SafetyEvent | RigEventRecord] = (),
    ) -> None:
        """Store one trial and the safety events since the last write (options checked)."""
        names = self.names(session)
        if names is None:
            raise ValueError(f"session {session!r} has no option set: begin it with begin_session")
        for field in ("option", "human", "robot"):
            value = getattr(rec, field)
            if value is not None and not 0 <= value < len(names):
                raise ValueError(f"trial {rec.trial}: {field} {value} is not one of {list(names)}")
        with self.db:
            self.db.execute("BEGIN")
            self.db.execute(
                "INSERT OR REPLACE INTO option_trials VALUES "
                "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (session, *astuple(rec)),
            )
            # the paper's store's own writers, in this transaction: one trial, its events, at once
            self.store._events(session, events)
            self.store._close_attempt(session, rec.trial)

    def set_clicks(self, session: str, trial: int, clicks: int | None) -> OptionsTrialRecord:
        """Enter a stored trial's counter clicks and rescore it (`Store.set_clicks`' rule)."""
        stored = {t.trial: t for t in self.trials(session)}.get(trial)
        points = self.store.write_clicks("option_trials", session, trial, stored, clicks)
        assert stored is not None  # write_clicks refused a missing trial
        return replace(stored, clicks=clicks, score=points)

    def trials(self, session: str) -> list[OptionsTrialRecord]:
        """A session's stored trials, in order."""
        rows = self.db.execute(
            "SELECT * FROM option_trials WHERE session = ? ORDER BY trial", (session,)
        )
        return [OptionsTrialRecord(*row[1:]) for row in rows]


def export_rows(db: sqlite3.Connection) -> dict[str, tuple[list[str], list[tuple[Any, ...]]]]:
    """option_sets and option_trials as (header, rows), option indices with their names too.

    `db`: a store's connection, or `nod export`'s union of stores. Nothing (no tables) when no
    session of N_o options was ever stored; a read never creates the tables.
    """
    have = {r[0] for r in db.execute(
        "SELECT name FROM sqlite_master WHERE type IN ('table', 'view') "
        "UNION SELECT name FROM sqlite_temp_master WHERE type = 'view'")}
    if "option_sets" not in have:
        return {}
    sets = [(s, n, names) for s, n, names in db.execute(
        "SELECT session, n_options, names FROM option_sets ORDER BY session")]
    named = {s: json.loads(names) for s, _, names in sets}
    cur = db.execute("SELECT * FROM option_trials ORDER BY session, trial")
    trial_cols = [c[0] for c in cur.description]
    rows = []
    for row in cur:
        rec = dict(zip(trial_cols, row, strict=True))
        names = named[rec["session"]]
        rows.append((*row, *(None if rec[f] is None else names[rec[f]]
                             for f in ("option", "human", "robot"))))
    return {
        "option_sets": (["session", "n_options", "names"], sets),
        "option_trials": (trial_cols + ["option_name", "human_name", "robot_name"], rows),
    }
