"""Simulated cohorts in the store (`nod cohort`): table `cohorts`, one row per run of the command.

A cohort is `participants` sessions named `<prefix>-<seed>` for the seeds `first_seed` on,
simulated with one configuration (kept here as JSON, so `nod cohort --resume` simulates the
rest with exactly it). Its row is written 'running' before the first session is stored and
'complete' after the last; a run that stops half-way (its cluster died, Ctrl-C) marks it
'incomplete' with why, and a run killed outright leaves it 'running'. Either way the store
holds part of a cohort, which no analysis may take for the whole: `unfinished` lists them and
`refuse_unfinished` is the one line the analysis commands say.

The table is created when a cohort is first recorded or looked for (`CREATE TABLE IF NOT
EXISTS`): a store written before it existed simply has no cohort rows, and its cohort sessions
read as before.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from services.store.store import Store

COHORTS_SCHEMA = """
CREATE TABLE IF NOT EXISTS cohorts (
    prefix       TEXT NOT NULL,
    first_seed   INTEGER NOT NULL,
    participants INTEGER NOT NULL,
    samples      INTEGER NOT NULL CHECK (samples IN (0, 1)),
    config       TEXT NOT NULL,
    status       TEXT NOT NULL CHECK (status IN ('running', 'incomplete', 'complete')),
    started_ns   INTEGER NOT NULL,
    finished_ns  INTEGER,
    note         TEXT NOT NULL DEFAULT '',
    PRIMARY KEY (prefix, first_seed)
);
"""


@dataclass(frozen=True, slots=True)
class CohortRecord:
    """One run of `nod cohort`, as stored."""

    prefix: str
    first_seed: int
    participants: int
    samples: bool  # whether its sessions store samples (not --no-samples)
    config: str  # the NodConfig as JSON (dataclasses.asdict)
    status: str  # 'running', 'incomplete' or 'complete'
    started_ns: int  # wall clock
    finished_ns: int | None
    note: str  # why it is incomplete

    @property
    def seeds(self) -> range:
        """The seeds of its participants."""
        return range(self.first_seed, self.first_seed + self.participants)

    def session(self, seed: int) -> str:
        """The session name of the participant with this seed."""
        return f"{self.prefix}-{seed}"

    def describe(self) -> str:
        """'cohort-1…cohort-60 (60 participants)', for messages."""
        last = self.first_seed + self.participants - 1
        return (
            f"{self.session(self.first_seed)}…{self.session(last)} "
            f"({self.participants} participants)"
        )


def _ensure(store: Store) -> None:
    store.db.executescript(COHORTS_SCHEMA)


def begin_cohort(
    store: Store, prefix: str, first_seed: int, participants: int, samples: bool, config: dict
) -> CohortRecord:
    """Record a new cohort as running (before any of its sessions is stored)."""
    _ensure(store)
    record = CohortRecord(
        prefix, first_seed, participants, samples, json.dumps(config, sort_keys=True),
        "running", time.time_ns(), None, "",
    )
    with store.transaction():
        store.db.execute(
            "INSERT INTO cohorts VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (record.prefix, record.first_seed, record.participants, int(record.samples),
             record.config, record.status, record.started_ns, None, ""),
        )
    return record


def set_status(store: Store, cohort: CohortRecord, status: str, note: str = "") -> None:
    """Mark a cohort 'running' again, 'incomplete' (with why) or 'complete'."""
    finished = time.time_ns() if status == "complete" else None
    with store.transaction():
        store.db.execute(
            "UPDATE cohorts SET status = ?, note = ?, finished_ns = ? "
            "WHERE prefix = ? AND first_seed = ?",
            (status, note, finished, cohort.prefix, cohort.first_seed),
        )


def cohorts(store: Store) -> list[CohortRecord]:
    """Every recorded cohort, in the order they were started."""
    _ensure(store)
    rows = store.db.execute(
        "SELECT prefix, first_seed, participants, samples, config, status, started_ns, "
        "finished_ns, note FROM cohorts ORDER BY started_ns, prefix, first_seed"
    )
    return [
        CohortRecord(p, s, n, bool(k), c, st, t0, t1, note)
        for p, s, n, k, c, st, t0, t1, note in rows
    ]


def unfinished(store: Store) -> list[CohortRecord]:
    """The cohorts this store holds only part of ('running' or 'incomplete')."""
    return [c for c in cohorts(store) if c.status != "complete"]


def stored_sessions(store: Store, cohort: CohortRecord) -> dict[str, str]:
    """The cohort's sessions in the store, by name, with their status."""
    names = [cohort.session(s) for s in cohort.seeds]
    found: dict[str, str] = {}
    for i in range(0, len(names), 500):  # SQLite's bound on parameters
        part = names[i : i + 500]
        marks = ",".join("?" * len(part))
        found.update(
            (str(a), str(b))
            for a, b in store.db.execute(
                f"SELECT session, status FROM sessions WHERE session IN ({marks})", part
            )
        )
    return found


def drop_session(store: Store, session: str) -> None:
    """Remove a session left half-stored (its trials and samples too), in one transaction."""
    with store.transaction():
        for table in ("samples", "trials", "option_sets", "sessions"):
            store.db.execute(f"DELETE FROM {table} WHERE session = ?", (session,))


def refuse_unfinished(store: Store, name: str) -> None:
    """ValueError (one line) if the store holds part of a cohort: no analysis takes it as whole."""
    left = unfinished(store)
    if not left:
        return
    first = left[0]
    done = sum(1 for s in stored_sessions(store, first).values() if s == "complete")
    why = f": {first.note}" if first.note else ""
    more = f" (and {len(left) - 1} more)" if len(left) > 1 else ""
    raise ValueError(
        f"{name} holds an incomplete cohort, {first.describe()}, {done} stored{why}{more}; "
        f"finish it with `nod cohort --db {name} --resume` before analysing it"
    )
