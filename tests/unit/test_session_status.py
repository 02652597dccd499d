"""A session's status as the store and the analysis report it: an aborted session (stopped
by its conductor: Ctrl-C, an abort) is *aborted*, never *interrupted*/crashed — only one left
'running' (its conductor died) is (services/store/store.py, services/analysis/sessions.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from services.analysis.sessions import select_sessions
from services.store import Store, TrialRecord


def _plain(n: int) -> TrialRecord:
    return TrialRecord(n, "dissensus" if n <= 3 else "consensus", None if n <= 3 else "red",
                       "neutral", 0.0, 0.0, 1, 2, "red", "red", "C", 0, 0, 10, 2, "pressed")


@pytest.fixture
def store(tmp_path: Path):
    s = Store(tmp_path / "s.db")
    for i, (sid, status, trials) in enumerate((
        ("s-done", "complete", 8), ("s-stopped", "aborted", 3), ("s-crashed", "running", 2),
        ("s-stopped-early", "aborted", 0), ("s-crashed-early", "running", 0),
    )):
        s.begin_session(sid, f"P{i + 1:02d}", "sim", i, i, {})
        for n in range(1, trials + 1):
            s.write_trial(sid, _plain(n), [])
        if status != "running":
            s.finish_session(sid, 100 + i, status)
    yield s
    s.close()


def test_only_sessions_left_running_are_reported_interrupted(store: Store) -> None:
    # `nod experiment` warns of these at start ("was interrupted after N stored trial(s)").
    assert sorted(store.interrupted_sessions()) == [("s-crashed", 2), ("s-crashed-early", 0)]


def test_the_analysis_says_aborted_for_an_aborted_session_and_crashed_for_a_running_one(
    store: Store,
) -> None:
    selection = select_sessions(store)
    assert [p.session for p in selection.participants] == ["s-done"]
    assert {e.session: (e.status, e.reason) for e in selection.excluded} == {
        "s-stopped": ("aborted", "aborted after 3 of 8 trials"),
        "s-stopped-early": ("aborted", "aborted after 0 of 8 trials"),
        "s-crashed": ("running", "running (crashed?) after 2 of 8 trials"),
        "s-crashed-early": ("running", "running (crashed?) after 0 of 8 trials"),
    }
