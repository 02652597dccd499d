"""Which sessions a study analyses: the inclusion rule, applied to a session store (SPEC §7).

By default only *complete* sessions count: status `complete` and every scheduled trial stored
(the schedule is the session's stored protocol, else SPEC's 8 trials); an interrupted trial is
stored, so a complete session may still lose trials trial-wise. With `min_trials = N` instead,
a session with at least N *scored* trials (stored and not interrupted) counts, whatever its
status. Of a participant's sessions that pass, the latest is analysed. Every other session is
an `ExcludedSession` with its reason, in the words the report prints: "aborted after 4 of 8
trials", "running (crashed?) after 2 of 8 trials", "superseded by the later session …".

A participant who withdrew is no excluded session: their sessions are not read at all
(`services.store.withdrawals.withdrawn_filter`, the one selection `nod export` and `nod fit`
apply too), unless the filter includes them (`--include-withdrawn`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from services.model.geometry import COLOURS
from services.model.phases import CONTROL_TRIALS
from services.store import Store
from services.store.withdrawals import WithdrawnFilter, withdrawn_filter

OUTCOMES: tuple[str, ...] = ("C", "CH", "D", "DH")
TRIALS: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 7, 8)


@dataclass(frozen=True, slots=True)
class ParticipantOutcomes:
    """One participant's analysed session: trial number → outcome (None: timeout)."""

    participant: str
    session: str
    status: str
    outcomes: Mapping[int, str | None]  # stored trials only; a missing trial has no key
    interrupted: frozenset[int] = frozenset()  # stored as interrupted (their outcome is None)
    control_labels: str = "agreement"  # the rule that labelled its control trials (SPEC §6)
    rig: str = ""  # the rig its conductor ran it on
    options: tuple[str, ...] = COLOURS  # the session's option set (the paper's)
    # per stored trial, (O, the human's press, the robot's press) by option name (None: none)
    choices: Mapping[int, tuple[str | None, str | None, str | None]] = field(
        default_factory=dict
    )

    def outcome(self, trial: int) -> str | None:
        """The trial's outcome, or None for a timeout or a trial never stored."""
        return self.outcomes.get(trial)


@dataclass(frozen=True, slots=True)
class InclusionRule:
    """The sessions that enter the analysis: complete ones, or those with ≥ N scored trials."""

    min_trials: int | None = None  # None: complete sessions only; else ≥ 1 scored trials

    def __post_init__(self) -> None:
        if self.min_trials is not None and self.min_trials < 1:
            raise ValueError(f"--min-trials must be at least 1, got {self.min_trials}")

    def describe(self) -> str:
        """The rule in one sentence, as every report states it."""
        if self.min_trials is None:
            return (
                "complete sessions only (status complete and every scheduled trial stored); "
                "--min-trials N includes incomplete sessions with at least N scored trials"
            )
        return (
            f"sessions with at least {self.min_trials} scored trial(s) (stored and not "
            "interrupted), whatever their status; the missing trials are excluded trial-wise"
        )

    def label(self) -> str:
        """The rule in a few words ("complete sessions only")."""
        if self.min_trials is None:
            return "complete sessions only"
        return f"sessions with ≥ {self.min_trials} scored trials"

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form: the rule's name, its parameter, a label and its sentence."""
        return {
            "rule": "complete" if self.min_trials is None else "min_trials",
            "min_trials": self.min_trials,
            "label": self.label(),
            "description": self.describe(),
        }


@dataclass(frozen=True, slots=True)
class ExcludedSession:
    """A session left out of the analysis, and why."""

    session: str
    participant: str
    status: str  # running, complete or aborted, as stored
    stored: int  # trials stored (interrupted ones included)
    scored: int  # trials stored and not interrupted
    scheduled: int  # trials of the session's protocol
    reason: str  # e.g. "aborted after 4 of 8 trials"

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {
            "session": self.session,
            "participant": self.participant,
            "reason": self.reason,
            "status": self.status,
            "trials_stored": self.stored,
            "trials_scored": self.scored,
            "trials_scheduled": self.scheduled,
        }


@dataclass(frozen=True, slots=True)
class Selection:
    """The sessions a rule lets in (one per participant), the ones it leaves out, and notes."""

    participants: list[ParticipantOutcomes]  # ordered by participant id
    excluded: list[ExcludedSession]  # in the order the sessions were started
    notes: list[str]
    rule: InclusionRule
    withdrawn: WithdrawnFilter = field(default_factory=lambda: WithdrawnFilter({}))

    def left_out(self) -> dict[str, str]:
        """Participants with no session let in, by participant: why their latest was not."""
        chosen = {p.participant for p in self.participants}
        return {e.participant: e.reason for e in self.excluded if e.participant not in chosen}


def scheduled_trials(config: str | None) -> int:
    """How many trials a session's stored protocol schedules (SPEC's 8 if it does not say)."""
    try:
        doc = json.loads(config or "{}")
        trials = doc["protocol"]["trials"]
    except (ValueError, KeyError, TypeError):  # no or an older config: the SPEC schedule
        return len(TRIALS)
    return len(trials) if isinstance(trials, list) and trials else len(TRIALS)


PAPER_MODES = [(t, "dissensus" if t in CONTROL_TRIALS else "consensus") for t in TRIALS]


def check_schedule(session: str, config: str | None) -> None:
    """Refuse a session whose stored option schedule is not trials 1-3 dissensus, 4-8 consensus.

    The study's statistics (control trials against experiment trials) need that structure; the
    paper's sessions and the default schedule of N options have it. ValueError, one line.
    """
    try:
        rows = json.loads(config or "{}")["option_schedule"]
        modes = [(int(r["index"]), str(r["mode"])) for r in rows]
    except (ValueError, KeyError, TypeError):
        return
    if modes and modes != PAPER_MODES:
        raise ValueError(
            f"session {session} ran another schedule than trials 1-3 dissensus, 4-8 consensus: "
            "the study statistics here need that structure"
        )


def control_labels(config: str | None) -> str:
    """The rule that labelled a session's control trials, as its stored protocol says.

    A store written before the rule existed has no `control_labels`: its control trials were
    labelled by switches, and are read as they were labelled.
    """
    try:
        rule = json.loads(config or "{}")["protocol"].get("control_labels", "switches")
    except (ValueError, KeyError, TypeError, AttributeError):
        return "switches"
    return rule if rule in ("agreement", "switches") else "switches"


def describe_labels(rule: str) -> str:
    """One sentence for a report: how the control trials were labelled."""
    if rule == "agreement":
        return ("control trials (1-3) labelled by agreement alone, C or D (SPEC §6; switches "
                "counted, not labelled)")
    if rule == "switches":
        return "control trials (1-3) labelled C/CH/D/DH by switches, like the consensus trials"
    return "control trials labelled by different rules in different sessions (see `sessions`)"


def _status_reason(status: str, stored: int, scheduled: int) -> str:
    """Why an incomplete session is incomplete, in the words of the report."""
    if status == "aborted":
        return f"aborted after {stored} of {scheduled} trials"
    if status == "running":
        return f"running (crashed?) after {stored} of {scheduled} trials"
    return f"{status} but only {stored} of {scheduled} trials stored"


def select_sessions(
    store: Store, rule: InclusionRule | None = None, withdrawn: WithdrawnFilter | None = None
) -> Selection:
    """Apply the inclusion rule to every stored session; the latest included one per participant.

    The sessions of withdrawn participants are not read (`withdrawn`: the store's own filter,
    leaving them out, when not given).
    """
    rule = rule or InclusionRule()
    withdrawn = withdrawn if withdrawn is not None else withdrawn_filter(store)
    parts: dict[str, ParticipantOutcomes] = {}
    latest: dict[str, ExcludedSession] = {}  # the facts of each participant's session so far
    excluded: list[ExcludedSession] = []
    notes: list[str] = []
    for s in withdrawn.sessions(store.sessions()):  # oldest first: later ones supersede
        sid, pid, status = str(s["session"]), str(s["participant"]), str(s["status"])
        check_schedule(sid, s.get("config"))
        trials = [t for _, t in store.trials(sid)]
        bad = sorted(
            {t.outcome for t in trials if t.outcome is not None and t.outcome not in OUTCOMES}
        )
        if bad:
            raise ValueError(f"session {sid}: unknown outcome(s) {bad}")
        scheduled = scheduled_trials(s.get("config"))
        numbers = {t.trial for t in trials}
        scored = sum(not t.interrupted for t in trials)
        complete = status == "complete" and numbers >= set(range(1, scheduled + 1))
        reason = None if complete else _status_reason(status, len(trials), scheduled)
        if rule.min_trials is not None:
            enough = scored >= rule.min_trials
            reason = None if enough else (
                f"{reason or 'complete'}: {scored} scored trial(s), fewer than --min-trials "
                f"{rule.min_trials}"
            )
        if reason is not None:
            excluded.append(ExcludedSession(sid, pid, status, len(trials), scored, scheduled,
                                            reason))
            continue
        for t in trials:
            if t.interrupted:  # broken by a safe stop or e-stop: never scored, never counted
                notes.append(
                    f"session {sid} ({pid}) trial {t.trial} was interrupted by a safe stop: "
                    "excluded"
                )
        part = ParticipantOutcomes(
            participant=pid,
            session=sid,
            status=status,
            outcomes={t.trial: None if t.interrupted else t.outcome for t in trials},
            interrupted=frozenset(t.trial for t in trials if t.interrupted),
            control_labels=control_labels(s.get("config")),
            rig=str(s.get("rig") or ""),
            options=store.option_names(sid),
            choices={t.trial: (t.option, t.human, t.robot) for t in trials},
        )
        if pid in latest:
            old = latest[pid]
            excluded.append(replace(old, reason=f"superseded by the later session {sid}"))
        latest[pid] = ExcludedSession(sid, pid, status, len(trials), scored, scheduled, "")
        parts[pid] = part
    return Selection([parts[p] for p in sorted(parts)], excluded, notes, rule, withdrawn)


def resolve_session(
    store: Store, session: str | None = None, participant: str | None = None
) -> tuple[str, str]:
    """The (session id, participant) a command names: by session id, by participant, or latest.

    `participant` picks that participant's latest session with stored trials. A `session` that
    is no session id but a participant id is read as the participant (`--session P01`, as the
    docs write it, works on `nod run` stores, whose session ids are hex). With neither, the
    latest session. ValueError, naming what the store has, when nothing matches.
    """
    rows = store.sessions()  # oldest first
    if not rows:
        raise ValueError(f"no sessions in {store.path}: run `nod run` first")
    by_id = {str(r["session"]): str(r["participant"]) for r in rows}
    if session is not None and session in by_id:
        if participant is not None and by_id[session] != participant:
            raise ValueError(f"session {session} is participant {by_id[session]}'s, not "
                             f"{participant}'s")
        return session, by_id[session]
    who = participant if participant is not None else session
    if who is None:
        last = str(rows[-1]["session"])
        return last, by_id[last]
    theirs = [str(r["session"]) for r in rows if str(r["participant"]) == who]
    with_trials = [s for s in theirs if store.trials(s)]
    if with_trials:
        return with_trials[-1], who
    if theirs:
        raise ValueError(f"participant {who} has no stored trials (sessions: {', '.join(theirs)})")
    people = sorted(set(by_id.values()))
    shown = ", ".join(people[:8]) + (", …" if len(people) > 8 else "")
    what = "participant" if participant is not None else "session or participant"
    raise ValueError(f"no {what} {who!r} in {store.path}; participants: {shown}")
