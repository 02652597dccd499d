"""A study database read for the fit: each participant's analysed session as `TrialPath`s.

The sessions fitted are the ones `nod analyze study` analyses: its inclusion rule
(`services.analysis.sessions.select_sessions`: complete sessions only, or with `min_trials`
those with at least N scored trials; the latest that passes per participant), with withdrawn
participants left out (`services.store.withdrawals`) unless `include_withdrawn`. Whom each rule
leaves out is one line (`FitStudy.notes`).

The bad inputs a lab meets end here, each as one `FitInputError` line that says what to do: a
database with no sessions, a participant with no complete trial, a database whose trials keep
no hand samples (landmarks or their centre), which the fit reads.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

from services.analysis.sessions import InclusionRule, select_sessions
from services.core.config import from_mapping
from services.model.geometry import COLOURS, TableLayout
from services.model.summaries import HandPath, TrialPath, complete_trials
from services.store import Sample, Store, TrialRecord, unpack_landmarks
from services.store.cohorts import refuse_unfinished
from services.store.withdrawals import INCLUDE_FLAG, withdrawn_filter


class FitInputError(ValueError):
    """The study cannot be fitted as given; the message is one line saying how to fix it."""


@dataclass(frozen=True, slots=True)
class Person:
    """One participant's session as the fit reads it."""

    participant: str
    session: str
    paths: tuple[TrialPath, ...]
    outcomes: tuple[str | None, ...]  # per stored trial, in trial order
    layout: TableLayout


def _centre(s: Sample) -> tuple[float, float] | None:
    """The hand centre of a sample: stored, or the mean of its landmarks."""
    if s.hand_x is not None and s.hand_y is not None:
        return s.hand_x, s.hand_y
    points = unpack_landmarks(s.landmarks)
    if not points:
        return None
    return (sum(p[0] for p in points) / len(points), sum(p[1] for p in points) / len(points))


def trial_path(rec: TrialRecord, samples: list[Sample]) -> TrialPath:
    """A stored trial as the summaries read it (times from its "go")."""
    t_go = rec.t_go_ns if rec.t_go_ns is not None else (samples[0].t_ns if samples else 0)
    path = HandPath()
    for s in samples:
        c = _centre(s) if s.detected else None
        if c is not None:
            path.add((s.t_ns - t_go) / 1e9, *c)
    return path.trial(rec.trial, rec.mode, rec.yaw, rec.human, rec.robot, rec.switches,
                      rec.interrupted)


def _layout(config: str) -> TableLayout:
    """The table layout the session ran with (its stored configuration), SPEC's if absent."""
    try:
        stored = json.loads(config).get("layout")
    except (ValueError, AttributeError):
        stored = None
    if not isinstance(stored, dict):
        return TableLayout()
    try:
        return from_mapping(TableLayout, stored)
    except (ValueError, TypeError):
        return TableLayout()


@dataclass(frozen=True, slots=True)
class FitStudy:
    """What `read_study` read: the people to fit, those skipped, and who was left out."""

    people: list[Person]
    skipped: list[str]  # one line per participant with nothing to fit
    notes: list[str]  # one line per rule that left participants out (withdrawn, inclusion)


def _left_out_line(left: dict[str, str], rule: InclusionRule) -> str | None:
    """One line naming the participants the inclusion rule left out, and why."""
    if not left:
        return None
    who = ", ".join(f"{p} ({why})" for p, why in sorted(left.items()))
    more = ("; --min-trials N fits sessions with at least N scored trials"
            if rule.min_trials is None else "")
    return f"left out (inclusion rule: {rule.label()}): {who}{more}"


def two_options_only(participant: str, options: tuple[str, ...]) -> str:
    """Why a session of another option set is not fitted, in one line."""
    return (
        f"participant {participant!r} ran options {', '.join(options)}: the fit is defined for "
        "the paper's two options only (its simulated person and estimator are trained on "
        "two-option sessions; docs/multi-option.md)"
    )


def read_study(
    db: Path, participant: str | None = None, rule: InclusionRule | None = None,
    include_withdrawn: bool = False,
) -> FitStudy:
    """Each participant's session that the inclusion rule lets in (module docstring).

    FitInputError for a missing or empty database, a database without hand samples, and a
    `participant` who is not there, withdrew, was left out by the rule or has no complete trial.
    """
    rule = rule or InclusionRule()
    if not db.is_file():
        raise FitInputError(f"no such database: {db}; give the study's --db")
    store = Store(db)
    try:
        try:
            refuse_unfinished(store, str(db))
        except ValueError as exc:
            raise FitInputError(str(exc)) from None
        sessions = {str(s["session"]): s for s in store.sessions()}
        if not sessions:
            raise FitInputError(f"{db} holds no sessions: run the study (or `nod cohort`) first")
        keep = withdrawn_filter(store, include_withdrawn)
        chosen = select_sessions(store, rule, keep)
        left = chosen.left_out()
        other = {p.participant: p.options for p in chosen.participants if p.options != COLOURS}
        if other:  # defined for two options only: say so in one line, fit the rest
            chosen = replace(chosen, participants=[
                p for p in chosen.participants if p.participant not in other])
            if participant in other:
                raise FitInputError(two_options_only(participant, other[participant]))
        if participant is not None:
            if not keep.keeps(participant):
                raise FitInputError(f"participant {participant!r} withdrew from the study: not "
                                    f"fitted ({INCLUDE_FLAG} fits them)")
            if participant in left:
                raise FitInputError(
                    f"participant {participant!r} has no session the inclusion rule "
                    f"({rule.label()}) lets in: {left[participant]}"
                    + ("; --min-trials N fits it" if rule.min_trials is None else ""))
            if participant not in {p.participant for p in chosen.participants}:
                known = ", ".join(sorted(p.participant for p in chosen.participants)[:8])
                raise FitInputError(f"participant {participant!r} has no stored trials in {db} "
                                    f"(participants with trials: {known or 'none'})")
            left = {}
        notes = [n for n in (keep.note() if participant is None else None,
                             _left_out_line(left, rule)) if n]
        if other and participant is None:
            notes.append("left out (the fit is defined for two options only): " + ", ".join(
                f"{who} ({', '.join(names)})" for who, names in sorted(other.items())))
        if not chosen.participants:
            if other:
                who = min(other)
                raise FitInputError(two_options_only(who, other[who]))
            if left:
                raise FitInputError(f"no session of {db} passes the inclusion rule: "
                                    f"{_left_out_line(left, rule)}")
            raise FitInputError(f"{db} holds no sessions with trials to fit"
                                + (f" ({notes[0]})" if notes else ""))
        (with_hand,) = store.db.execute(
            "SELECT COUNT(*) FROM samples WHERE hand_x IS NOT NULL OR landmarks IS NOT NULL"
        ).fetchone()
        if not with_hand:
            raise FitInputError(
                f"{db} stores no hand samples (landmarks): the fit reads the hand's path; "
                "record sessions with samples (a cohort: without --no-samples)")
        people: list[Person] = []
        skipped: list[str] = []
        for part in chosen.participants:
            who, session = part.participant, part.session
            if participant is not None and who != participant:
                continue
            trials = [rec for _, rec in store.trials(session)]
            paths = tuple(trial_path(rec, list(store.samples(session, rec.trial)))
                          for rec in trials)
            if not complete_trials(paths):
                line = (f"participant {who!r} (session {session}) has no complete trial "
                        "(every one interrupted or without hand samples): nothing to fit")
                if participant is not None:
                    raise FitInputError(line)
                skipped.append(line)
                continue
            people.append(Person(who, session, paths, tuple(r.outcome for r in trials),
                                 _layout(str(sessions[session]["config"]))))
        return FitStudy(people, skipped, notes)
    finally:
        store.close()
