"""Where a study stands: each participant of the study file against the session store.

A participant is *done* with a complete session, *running* with a session that has not ended
(a conductor at work, or one that crashed: `nod experiment --resume SESSION`), *aborted* when
their only sessions were stopped before the end, and *left* with none. The next participant is
the first one left, by slot, who has not refused consent. A participant who withdrew
(`services.store.withdrawals`) is *withdrawn*, whatever their sessions: never next, never
resumed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, TypeAlias

from services.model.counterbalance import position_counts
from services.store import Store
from services.store.participants import (
    Consent,
    SessionSummary,
    consents,
    sessions_by_participant,
)
from services.store.policies import read_policies
from services.store.withdrawals import Withdrawal, withdrawals
from services.study.studyfile import Entry, Study

Status: TypeAlias = Literal["done", "running", "aborted", "left", "withdrawn"]
STATUSES: tuple[Status, ...] = ("done", "running", "aborted", "left", "withdrawn")


@dataclass(frozen=True, slots=True)
class Standing:
    """One participant: their entry, sessions (oldest first), consent and withdrawal."""

    entry: Entry
    sessions: tuple[SessionSummary, ...]
    consent: Consent | None
    withdrawal: Withdrawal | None = None
    policies: dict[str, tuple[str, str]] = field(default_factory=dict)  # session: (name, sha)

    @property
    def status(self) -> Status:
        """done, running, aborted, left or withdrawn (the module's docstring)."""
        if self.withdrawal is not None:
            return "withdrawn"
        kinds = {s.status for s in self.sessions}
        if "complete" in kinds:
            return "done"
        if "running" in kinds:
            return "running"
        return "aborted" if kinds else "left"

    @property
    def session(self) -> SessionSummary | None:
        """The session that decides the status (the last complete one, else the latest)."""
        done = [s for s in self.sessions if s.status == "complete"]
        return done[-1] if done else (self.sessions[-1] if self.sessions else None)

    @property
    def order_mismatch(self) -> bool:
        """Whether the deciding session ran another O order than the roster's."""
        s = self.session
        return s is not None and s.options is not None and s.options != self.entry.order

    @property
    def policy_ran(self) -> tuple[str, str] | None:
        """(name, SHA-256) of the robot policy the deciding session ran (None: none stored)."""
        s = self.session
        return None if s is None else self.policies.get(s.session)


@dataclass(frozen=True, slots=True)
class Roster:
    """The whole study against one store."""

    study: Study
    standings: tuple[Standing, ...]
    strangers: dict[str, int]  # participants with sessions in the store who are not in the study

    def counts(self) -> dict[Status, int]:
        """How many participants are in each status."""
        return {k: sum(s.status == k for s in self.standings) for k in STATUSES}

    def next(self) -> Standing | None:
        """The first participant left, by slot, who has not refused consent (or None)."""
        for s in self.standings:
            if s.status == "left" and (s.consent is None or s.consent.consent):
                return s
        return None

    def standing(self, participant: str) -> Standing | None:
        """One participant's standing (None: not in the study)."""
        return next((s for s in self.standings if s.entry.id == participant), None)

    def balance(self) -> list[tuple[int, ...]]:
        """How often each option is O at each consensus trial, over those who are done.

        Per option of the study's set, in its order: (red, blue) for the paper's.
        """
        done = [s.entry.order for s in self.standings if s.status == "done"]
        return position_counts(done, self.study.options)

    def as_json(self) -> dict[str, Any]:
        """The roster as a JSON document (`nod study status --json`)."""
        nxt = self.next()
        pc = self.study.policy_conditions
        doc: dict[str, Any] = {
            "study": self.study.name,
            "method": self.study.counterbalance.method,
            "block": self.study.counterbalance.block,
            "options": list(self.study.options),
            "consensus_trials": list(self.study.conditions.consensus),
            "counts": self.counts(),
            "next": None if nxt is None else nxt.entry.id,
            "participants": [
                {
                    "id": s.entry.id,
                    "slot": s.entry.slot,
                    "order": list(s.entry.order),
                    "status": s.status,
                    "consent": None if s.consent is None else s.consent.consent,
                    "demographics": {} if s.consent is None else s.consent.demographics,
                    "withdrawn": None if s.withdrawal is None else {
                        "withdrawn_ns": s.withdrawal.withdrawn_ns,
                        "reason": s.withdrawal.reason,
                        "deleted": s.withdrawal.deleted,
                        "counts": s.withdrawal.counts,
                    },
                    "sessions": [
                        {
                            "session": x.session,
                            "status": x.status,
                            "trials": x.trials,
                            "order": None if x.options is None else list(x.options),
                            "again": x.again,
                        }
                        for x in s.sessions
                    ],
                }
                for s in self.standings
            ],
            "not_in_study": self.strangers,
        }
        if pc is not None:  # a study without policy conditions: the document as it always was
            doc["conditions"] = dict(pc.policies)
            doc["assignment"] = pc.assignment
            for row, s in zip(doc["participants"], self.standings, strict=True):
                row["condition"] = s.entry.condition
                for x in row["sessions"]:
                    ran = s.policies.get(x["session"])
                    x["policy"] = None if ran is None else {"name": ran[0], "sha256": ran[1]}
        return doc


def roster(study: Study, store: Store) -> Roster:
    """The study's participants with their sessions and consent from the store."""
    sessions = sessions_by_participant(store)
    consent = consents(store)
    gone = withdrawals(store)
    ran = {k: (p.policy, p.sha256) for k, p in read_policies(store).items()}
    standings = tuple(
        Standing(e, tuple(sessions.get(e.id, [])), consent.get(e.id), gone.get(e.id),
                 {x.session: ran[x.session] for x in sessions.get(e.id, []) if x.session in ran})
        for e in study.participants
    )
    ids = {e.id for e in study.participants}
    strangers = {p: len(v) for p, v in sessions.items() if p not in ids}
    return Roster(study, standings, strangers)
