"""Participants in the store: consent and demographics, each session's O order, reused ids.

Three things a study needs beyond the trials (tables `participants` and `session_orders` of
`services.store.store.SCHEMA`):

- consent per participant (given or refused, when, and optional demographics as JSON), recorded
  by `nod study consent` and required by `nod study start`;
- the O order each session ran (the option of each consensus trial, as JSON), recorded by the
  conductor at the session's start, and why a participant who already had a session got
  another (`--again REASON`);
- who has sessions already, so a reused participant id is refused.

A participant who withdrew is no refusal of consent but a row of `withdrawals` (the difference,
and what it does to every reader: `services.store.withdrawals`); their id is never free again.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from services.store.store import Store
from services.store.withdrawals import withdrawal_problem, withdrawn

ID_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,31}")


def check_id(participant: str) -> str:
    """A participant id as stored: 1-32 letters, digits, `_`, `.`, `-` (ValueError if not)."""
    if not ID_PATTERN.fullmatch(participant):
        raise ValueError(
            f"participant id {participant!r} must be 1-32 letters, digits, '_', '.' or '-', "
            "starting with a letter or digit"
        )
    return participant


@dataclass(frozen=True, slots=True)
class Consent:
    """One participant's consent record."""

    participant: str
    consent: bool  # False: refused or withdrawn
    consented_ns: int  # wall-clock ns when it was recorded
    demographics: dict[str, str] = field(default_factory=dict)  # age, handedness, notes


@dataclass(frozen=True, slots=True)
class SessionSummary:
    """A stored session of one participant, as the roster needs it."""

    session: str
    participant: str
    status: str  # running | complete | aborted
    started_ns: int
    trials: int  # trials stored so far
    options: tuple[str, ...] | None  # the O order it ran (None: a session of an older version)
    again: str | None  # why this participant got another session


def record_consent(
    store: Store, participant: str, consent: bool, t_ns: int, demographics: dict[str, str]
) -> None:
    """Store (or replace) a participant's consent and demographics."""
    with store.transaction():
        store.db.execute(
            "INSERT OR REPLACE INTO participants VALUES (?, ?, ?, ?)",
            (check_id(participant), int(consent), t_ns, json.dumps(demographics, sort_keys=True)),
        )


def consent_of(store: Store, participant: str) -> Consent | None:
    """A participant's consent record, or None if none was recorded."""
    row = store.db.execute(
        "SELECT participant, consent, consented_ns, demographics FROM participants "
        "WHERE participant = ?",
        (participant,),
    ).fetchone()
    return None if row is None else _consent(row)


def consents(store: Store) -> dict[str, Consent]:
    """Every consent record, by participant."""
    rows = store.db.execute(
        "SELECT participant, consent, consented_ns, demographics FROM participants"
    )
    return {str(r[0]): _consent(r) for r in rows}


def _consent(row: Sequence[Any]) -> Consent:
    return Consent(str(row[0]), bool(row[1]), int(row[2]), json.loads(row[3]))


def record_order(
    store: Store,
    session: str,
    participant: str,
    options: Sequence[str],
    again: str | None,
    t_ns: int,
) -> None:
    """Store the O order a session runs, and why it is another session of its participant."""
    with store.transaction():
        store.db.execute(
            "INSERT OR REPLACE INTO session_orders VALUES (?, ?, ?, ?, ?)",
            (session, participant, json.dumps(list(options)), again, t_ns),
        )


def order_of_session(store: Store, session: str) -> tuple[str, ...] | None:
    """The O order a session was started with, or None if none was stored."""
    row = store.db.execute(
        "SELECT options FROM session_orders WHERE session = ?", (session,)
    ).fetchone()
    return None if row is None else tuple(json.loads(row[0]))


def sessions_by_participant(store: Store) -> dict[str, list[SessionSummary]]:
    """Every stored session with its trial count and order, by participant, oldest first."""
    rows = store.db.execute(
        "SELECT s.session, s.participant, s.status, s.started_ns, "
        "(SELECT COUNT(*) FROM trials t WHERE t.session = s.session), o.options, o.again "
        "FROM sessions s LEFT JOIN session_orders o ON o.session = s.session "
        "ORDER BY s.started_ns, s.session"
    )
    out: dict[str, list[SessionSummary]] = {}
    for session, participant, status, started, trials, options, again in rows:
        opts = None if options is None else tuple(json.loads(options))
        summary = SessionSummary(
            str(session), str(participant), str(status), int(started), int(trials), opts, again
        )
        out.setdefault(summary.participant, []).append(summary)
    return out


def reuse_problem(store: Store, participant: str, complete_only: bool = False) -> str | None:
    """Why `participant` may not start a new session without `--again`, or None if they may.

    A participant with a complete session has done the study; one with a running or aborted
    session is resumed (`nod experiment --resume SESSION`), not started again. `complete_only`:
    only a complete session counts (what `nod experiment` refuses on its own). A participant
    who withdrew may not run at all (`withdrawal_problem`), `--again` or not.
    """
    if problem := withdrawal_problem(store, participant):
        return problem
    sessions = sessions_by_participant(store).get(participant, [])
    if complete_only:
        sessions = [s for s in sessions if s.status == "complete"]
    if not sessions:
        return None
    done = [s for s in sessions if s.status == "complete"]
    if done:
        return (
            f"participant {participant} already has a complete session ({done[-1].session}, "
            f"{done[-1].trials} trials) in {store.path}; a new one needs --again 'why' "
            "(recorded with it)"
        )
    last = sessions[-1]
    return (
        f"participant {participant} has a {last.status} session {last.session} after "
        f"{last.trials} trial(s) in {store.path}: go on with it with `nod experiment --resume "
        f"{last.session}`, or start a new one with --again 'why' (recorded with it)"
    )


def next_free_ids(store: Store, n: int, prefix: str = "P") -> list[str]:
    """The first n ids `<prefix>01`, `<prefix>02`, … with no stored session and no withdrawal.

    A withdrawn participant whose data was deleted has no session left, but their id stays
    taken: a new person under it would be left out as withdrawn.
    """
    return first_free_ids(set(sessions_by_participant(store)) | withdrawn(store), n, prefix)


def first_free_ids(taken: set[str], n: int, prefix: str = "P") -> list[str]:
    """The first n ids `<prefix>01`, `<prefix>02`, … not in `taken`."""
    out: list[str] = []
    k = 0
    while len(out) < n:
        k += 1
        candidate = f"{prefix}{k:02d}"
        if candidate not in taken:
            out.append(candidate)
    return out
