"""A session's stored rows read back as records, on any connection to a store.

One query per kind of row, shared by `Store` (its own file) and the readers of several stores
at once (`services.store.study_stores.union_of`, on which each table is the union of the
stores' rows: `nod export --bids`), so the columns, their order and the rows' order are written
once.
"""

from __future__ import annotations

import sqlite3

from services.store.records import Interruption, RigEventRecord, SafetyEvent, TrialRecord


def trials(db: sqlite3.Connection, session: str) -> list[TrialRecord]:
    """A session's trials, in order."""
    cur = db.execute("SELECT * FROM trials WHERE session = ? ORDER BY trial", (session,))
    cols = [c[0] for c in cur.description]
    out: list[TrialRecord] = []
    for row in cur:
        fields = dict(zip(cols, row, strict=True))  # by name: the columns a migration added
        fields.pop("session")
        fields["interrupted"] = bool(fields["interrupted"])
        out.append(TrialRecord(**fields))
    return out


def rig_events(db: sqlite3.Connection, session: str) -> list[RigEventRecord]:
    """A session's launcher events (restarts and the like) in time order."""
    cur = db.execute(
        "SELECT trial, attempt, t_ns, host, service, kind, code, text FROM rig_events "
        "WHERE session = ? ORDER BY t_ns",
        (session,),
    )
    return [RigEventRecord(*row) for row in cur]


def safety_events(db: sqlite3.Connection, session: str) -> list[SafetyEvent]:
    """A session's safety events in time order."""
    cur = db.execute(
        "SELECT trial, attempt, t_ns, device, event, reason FROM safety_events "
        "WHERE session = ? ORDER BY t_ns",
        (session,),
    )
    return [SafetyEvent(*row) for row in cur]


def interruptions(db: sqlite3.Connection, session: str) -> list[Interruption]:
    """A session's broken trial starts, in order."""
    cur = db.execute(
        "SELECT trial, attempt, t_start_ns, t_ns, reason FROM interruptions "
        "WHERE session = ? ORDER BY trial, attempt",
        (session,),
    )
    return [Interruption(*row) for row in cur]
