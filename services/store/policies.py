"""The robot policy of each session and its settings per trial (issue 36).

`policy_cohorts`: the policy a `nod cohort` run was begun with (so `--resume` knows it).
`policy_sessions`: a session's policy (its name and its file's SHA-256) and, for a simulated
participant, the kind of person the simulator drew (strategist, contrarian, firm, rest; NULL
for a real one). `policy_trials`: the settings the policy chose for each trial (b*, the gaze
level toward O, u_r). A session stored without a policy has no rows: today's robot.
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass

from services.model.policy import PolicySettings
from services.store.store import Store


@dataclass(frozen=True, slots=True)
class SessionPolicy:
    """A session's policy as stored."""

    session: str
    policy: str
    sha256: str
    kind: str | None
    trials: dict[int, PolicySettings]


def write_policy(
    store: Store, session: str, policy: str, sha256: str, kind: str | None,
    trials: dict[int, PolicySettings],
) -> None:
    """Store a session's policy and its settings per trial, in one transaction."""
    with store.transaction():
        store.db.execute("INSERT OR REPLACE INTO policy_sessions VALUES (?, ?, ?, ?)",
                         (session, policy, sha256, kind))
        store.db.executemany(
            "INSERT OR REPLACE INTO policy_trials VALUES (?, ?, ?, ?, ?)",
            [(session, i, s.b_star, s.gaze_level, s.u_r) for i, s in sorted(trials.items())])


def begin_policy(store: Store, session: str, policy: str, sha256: str,
                 kind: str | None = None) -> None:
    """A session's policy on record as it starts (a resumed session's stays as it was)."""
    with store.db:
        store.db.execute("INSERT OR IGNORE INTO policy_sessions VALUES (?, ?, ?, ?)",
                         (session, policy, sha256, kind))


def write_policy_trial(store: Store, session: str, trial: int, s: PolicySettings) -> None:
    """The settings the policy chose for one trial (a repeated trial's: the last chosen)."""
    with store.db:
        store.db.execute("INSERT OR REPLACE INTO policy_trials VALUES (?, ?, ?, ?, ?)",
                         (session, trial, s.b_star, s.gaze_level, s.u_r))


def read_policies(store: Store | sqlite3.Connection) -> dict[str, SessionPolicy]:
    """Every session's stored policy, by session (a store, or a study's union connection)."""
    db = store.db if isinstance(store, Store) else store
    trials: dict[str, dict[int, PolicySettings]] = {}
    for session, trial, b, g, u in db.execute("SELECT * FROM policy_trials"):
        trials.setdefault(session, {})[int(trial)] = PolicySettings(float(b), g, float(u))
    return {
        s: SessionPolicy(s, p, h, k, trials.get(s, {}))
        for s, p, h, k in db.execute("SELECT * FROM policy_sessions ORDER BY session")
    }


def write_cohort_policy(store: Store, prefix: str, first_seed: int, policy: str,
                        sha256: str, text: str | None = None, built_on: str | None = None,
                        ) -> None:
    """Store the policy a cohort run was begun with.

    With its file's text and the configuration (JSON) of the people its table was simulated
    from, so that a resume rebuilds it.
    """
    with store.db:
        store.db.execute(
            "INSERT OR REPLACE INTO policy_cohorts (prefix, first_seed, policy, policy_sha256, "
            "policy_text, built_on) VALUES (?, ?, ?, ?, ?, ?)",
            (prefix, first_seed, policy, sha256, text, built_on))


@dataclass(frozen=True, slots=True)
class CohortPolicy:
    """The policy a cohort run was begun with, as stored."""

    name: str
    sha256: str
    text: str | None  # None: stored before the file's text was kept
    built_on: str | None


def cohort_policy(store: Store, prefix: str, first_seed: int) -> CohortPolicy | None:
    """The policy a cohort run was begun with; None: none was stored."""
    row = store.db.execute(
        "SELECT policy, policy_sha256, policy_text, built_on FROM policy_cohorts "
        "WHERE prefix = ? AND first_seed = ?", (prefix, first_seed)).fetchone()
    return None if row is None else CohortPolicy(str(row[0]), str(row[1]), row[2], row[3])
