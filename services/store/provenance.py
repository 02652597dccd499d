"""The `provenance` table: one row per conductor run of a session (`services.core.provenance`).

`nod experiment` writes a run's row as the session starts (`write_provenance`: code, inputs,
study) and completes it as the run ends (`finish_provenance`: the hosts heard, the recording and
its SHA-256), so a conductor killed mid-session leaves its start on record. A resumed session
has a row per run. A session stored before provenance was kept has none: its readers say
"unknown" rather than guess. A withdrawn participant's rows go with their sessions
(`services.store.withdrawals.delete_participant` deletes every table's rows of their sessions).
"""

from __future__ import annotations

import dataclasses
import json
import sqlite3
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from services.core.provenance import Provenance, file_sha256
from services.store.store import Store

FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(Provenance))


@dataclass(frozen=True, slots=True)
class SessionProvenance:
    """One run's stored provenance."""

    session: str
    started_ns: int  # wall clock, the run's start
    finished_ns: int | None  # wall clock, the run's end (None: it never ended cleanly)
    provenance: Provenance

    def as_dict(self) -> dict[str, object]:
        """The row as JSON (`nod report --json`)."""
        return {"session": self.session, "started_ns": self.started_ns,
                "finished_ns": self.finished_ns, **self.provenance.as_dict()}


def _db(where: Store | sqlite3.Connection) -> sqlite3.Connection:
    return where.db if isinstance(where, Store) else where


def write_provenance(store: Store, session: str, started_ns: int, prov: Provenance) -> None:
    """Store a run's provenance as it starts (a row of that run written again is replaced)."""
    values = [getattr(prov, f) for f in FIELDS]
    values[FIELDS.index("hosts")] = json.dumps(prov.as_dict()["hosts"])
    with store.transaction():
        store.db.execute(
            f"INSERT OR REPLACE INTO provenance (session, started_ns, {', '.join(FIELDS)}) "
            f"VALUES ({', '.join('?' * (len(FIELDS) + 2))})",
            (session, started_ns, *values),
        )


def finish_provenance(
    store: Store, session: str, started_ns: int, finished_ns: int,
    hosts: dict[str, tuple[str, ...]], recording: Path | None = None,
) -> str | None:
    """Complete a run's row: its hosts, its end and its recording's file and SHA-256.

    Returns why the recording has no digest (it cannot be read), or None.
    """
    digest, problem = None, None
    if recording is not None:
        try:
            digest = file_sha256(recording)
        except OSError as exc:
            problem = f"no digest of the recording {recording}: {exc.strerror or exc}"
    with store.transaction():
        store.db.execute(
            "UPDATE provenance SET hosts = ?, finished_ns = ?, recording_file = ?, "
            "recording_sha256 = ? WHERE session = ? AND started_ns = ?",
            (json.dumps({s: list(h) for s, h in sorted(hosts.items())}), finished_ns,
             None if recording is None else str(recording.resolve()), digest, session,
             started_ns),
        )
    return problem


def read_provenance(
    where: Store | sqlite3.Connection, sessions: Sequence[str] | None = None
) -> list[SessionProvenance]:
    """The stored runs (of `sessions`, or all), by session then start."""
    db = _db(where)
    cur = db.execute(
        f"SELECT session, started_ns, finished_ns, {', '.join(FIELDS)} FROM provenance "
        "ORDER BY session, started_ns"
    )
    wanted = None if sessions is None else set(sessions)
    out = []
    for row in cur:
        if wanted is not None and row[0] not in wanted:
            continue
        values = dict(zip(FIELDS, row[3:], strict=True))
        values["hosts"] = {s: tuple(h) for s, h in json.loads(values["hosts"] or "{}").items()}
        out.append(SessionProvenance(str(row[0]), int(row[1]),
                                     None if row[2] is None else int(row[2]),
                                     Provenance(**values)))
    return out
