"""A study database read for the fit: each participant's latest session as `TrialPath`s.

The bad inputs a lab meets end here, each as one `FitInputError` line that says what to do: a
database with no sessions, a participant with no complete trial, a database whose trials keep
no hand samples (landmarks or their centre), which the fit reads.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from services.core.config import from_mapping
from services.model.geometry import Colour, TableLayout
from services.model.summaries import TrialPath, complete_trials
from services.store import Sample, Store, TrialRecord, unpack_landmarks
from services.store.cohorts import refuse_unfinished


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


def _colour(value: str | None) -> Colour | None:
    return "red" if value == "red" else "blue" if value == "blue" else None


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
    ts: list[float] = []
    xs: list[float] = []
    ys: list[float] = []
    for s in samples:
        c = _centre(s) if s.detected else None
        if c is None or s.t_ns < t_go or (ts and (s.t_ns - t_go) / 1e9 <= ts[-1]):
            continue
        ts.append((s.t_ns - t_go) / 1e9)
        xs.append(c[0])
        ys.append(c[1])
    return TrialPath(rec.trial, rec.mode, rec.yaw, _colour(rec.human), _colour(rec.robot),
                     rec.switches, rec.interrupted, tuple(ts), tuple(xs), tuple(ys))


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


def read_study(db: Path, participant: str | None = None) -> tuple[list[Person], list[str]]:
    """Each participant's latest session with trials; (people, one line per one skipped).

    FitInputError for a missing or empty database, a database without hand samples, and a
    `participant` who is not there or has no complete trial.
    """
    if not db.is_file():
        raise FitInputError(f"no such database: {db}; give the study's --db")
    store = Store(db)
    try:
        try:
            refuse_unfinished(store, str(db))
        except ValueError as exc:
            raise FitInputError(str(exc)) from None
        sessions = store.sessions()
        if not sessions:
            raise FitInputError(f"{db} holds no sessions: run the study (or `nod cohort`) first")
        latest: dict[str, dict[str, object]] = {}
        for s in sessions:  # oldest first: a later session with trials replaces an earlier one
            n = store.db.execute("SELECT COUNT(*) FROM trials WHERE session = ?",
                                 (s["session"],)).fetchone()[0]
            if n:
                latest[str(s["participant"])] = s
        if participant is not None and participant not in latest:
            known = ", ".join(sorted(latest)[:8]) or "none"
            raise FitInputError(f"participant {participant!r} has no stored trials in {db} "
                                f"(participants with trials: {known})")
        (with_hand,) = store.db.execute(
            "SELECT COUNT(*) FROM samples WHERE hand_x IS NOT NULL OR landmarks IS NOT NULL"
        ).fetchone()
        if latest and not with_hand:
            raise FitInputError(
                f"{db} stores no hand samples (landmarks): the fit reads the hand's path; "
                "record sessions with samples (a cohort: without --no-samples)")
        people: list[Person] = []
        skipped: list[str] = []
        for who, s in latest.items():
            if participant is not None and who != participant:
                continue
            session = str(s["session"])
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
                                 _layout(str(s["config"]))))
        if not people and not skipped:
            raise FitInputError(f"{db} holds sessions but no trials: nothing to fit")
        return people, skipped
    finally:
        store.close()
