"""The participant's estimated parameters after each trial (issue 36, `nod estimate`).

`person_estimates`: one row per (session, trial, parameter): the estimate from trials
1..trial, its 90 % interval (a 0/1 parameter's set: low and high its least and largest value)
and a 0/1 parameter's probability of 1, with how many of those trials the estimator heard and
how long the estimate took. A session run without `nod estimate` has no rows.
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass

from services.store.store import Store


@dataclass(frozen=True, slots=True)
class ParamRow:
    """One parameter's estimate as stored."""

    name: str
    estimate: float
    low: float
    high: float
    probability: float | None


@dataclass(frozen=True, slots=True)
class TrialEstimate:
    """The estimate after one trial."""

    trial: int
    trials_seen: int
    seconds: float
    params: tuple[ParamRow, ...]


def write_estimate(store: Store, session: str, est: TrialEstimate) -> None:
    """Store one estimate (a second one after the same trial replaces it), in one transaction."""
    with store.transaction():
        store.db.execute("DELETE FROM person_estimates WHERE session = ? AND trial = ?",
                         (session, est.trial))
        store.db.executemany(
            "INSERT INTO person_estimates VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            [(session, est.trial, est.trials_seen, est.seconds, p.name, p.estimate, p.low,
              p.high, p.probability) for p in est.params])


def read_estimates(store: Store | sqlite3.Connection, session: str | None = None
                   ) -> dict[str, list[TrialEstimate]]:
    """The stored estimates by session, in trial order (`session`: that one only).

    From a store, or a study's union connection.
    """
    db = store.db if isinstance(store, Store) else store
    query = "SELECT * FROM person_estimates"
    rows = (db.execute(query + " WHERE session = ? ORDER BY trial, rowid", (session,))
            if session is not None else db.execute(query + " ORDER BY session, trial, rowid"))
    grouped: dict[str, dict[int, tuple[int, float, list[ParamRow]]]] = {}
    for s, trial, seen, seconds, name, est, low, high, prob in rows:
        entry = grouped.setdefault(s, {}).setdefault(int(trial), (int(seen), float(seconds), []))
        entry[2].append(ParamRow(name, float(est), float(low), float(high),
                                 None if prob is None else float(prob)))
    return {s: [TrialEstimate(t, seen, sec, tuple(ps)) for t, (seen, sec, ps) in sorted(by.items())]
            for s, by in grouped.items()}
