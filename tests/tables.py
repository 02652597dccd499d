"""A store's tables as rows, in a fixed order: for tests that compare two stores row for row
(a resumed cohort with an uninterrupted one, a cohort on a cluster with one in this process)."""

from __future__ import annotations

import sqlite3
from pathlib import Path


def trials_table(db: Path) -> list[tuple]:
    """Every row of the trials table, by session and trial."""
    with sqlite3.connect(db) as con:
        return con.execute("SELECT * FROM trials ORDER BY session, trial").fetchall()


def sessions_table(db: Path) -> list[tuple]:
    """Every row of the sessions table, by session."""
    with sqlite3.connect(db) as con:
        return con.execute("SELECT * FROM sessions ORDER BY session").fetchall()
