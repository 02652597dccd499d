"""A cohort whose cluster dies half-way: `nod cohort` says so in one line with the command that
finishes it, the store marks it incomplete (and no analysis takes it whole), and `nod cohort
--resume` completes it with the trials an uninterrupted run stores. The engine here runs the
sessions in this process and can be made to fail after some participants, like a scheduler
that dies (the real one: tests/integration/test_dask_tls.py)."""

from __future__ import annotations

import shlex
import sqlite3
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from services.compute.engine import Engine, EngineError
from services.fit.data import FitInputError, read_study
from services.sim import cohort as cohort_cli
from services.store import Store
from services.store.cohorts import cohorts, unfinished
from services.store.study_stores import open_stores
from tests.tables import sessions_table, trials_table


class InProcess(Engine):
    """fn over the items here, in order; the 'cluster' dies after `fail_after` results."""

    def __init__(self, fail_after: int | None = None) -> None:
        super().__init__(client=None, where="in process")  # type: ignore[arg-type]
        self.fail_after = fail_after
        self.ran: list[Any] = []

    def imap(self, fn: Callable, items: Sequence, chunk: int | None = None) -> Iterator:
        for i, item in enumerate(items):
            if i == self.fail_after:
                raise EngineError(
                    f"the cluster at tls://s:8786 stopped computing after {i} of {len(items)} "
                    "results (scheduler-connection-lost): restart its scheduler and workers"
                )
            self.ran.append(item)
            yield fn(item)


@pytest.fixture
def engines(monkeypatch: pytest.MonkeyPatch) -> list[InProcess]:
    """Each `nod cohort` run takes the next engine of the list."""
    queue: list[InProcess] = []

    @contextmanager
    def take(args: Any) -> Iterator[InProcess]:
        yield queue.pop(0)

    monkeypatch.setattr(cohort_cli, "engine_from_args", take)
    return queue


COHORT = ["--participants", "5", "--seed", "40", "--quiet", "--no-samples"]


def test_a_dead_cluster_leaves_an_incomplete_cohort_that_resume_completes(
    tmp_path: Path, engines: list[InProcess], capsys: pytest.CaptureFixture[str]
) -> None:
    whole, broken = tmp_path / "whole.sqlite", tmp_path / "broken.sqlite"
    engines += [InProcess(), InProcess(fail_after=2), InProcess()]
    assert cohort_cli.main([*COHORT, "--db", str(whole)]) == 0
    capsys.readouterr()
    assert cohort_cli.main([*COHORT, "--db", str(broken), "--scheduler", "tls://s:8786",
                            "--tls-dir", "/etc/nod/tls/dask/client"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "stopped computing after 2 of 5" in err and "2 of its 5 participants are stored" in err
    resume = err.split("finish it with: ", 1)[1]
    assert shlex.split(resume) == ["nod", "cohort", "--db", str(broken), "--resume",
                                   "--scheduler", "tls://s:8786", "--tls-dir",
                                   "/etc/nod/tls/dask/client", "--quiet"]
    store = Store(broken)
    try:
        (left,) = unfinished(store)
        assert left.status == "incomplete" and "stopped computing" in left.note
        assert len(store.sessions()) == 2
        # No analysis takes it for the whole cohort: one line each.
        with pytest.raises(ValueError, match=r"incomplete cohort, cohort-40…cohort-44 \(5 "
                           r"participants\), 2 stored.*nod cohort --db .* --resume"), \
                open_stores([broken]):
            pass
        with pytest.raises(FitInputError, match="incomplete cohort"):
            read_study(broken)
    finally:
        store.close()
    # Resume: the three participants not stored, with the cohort's own seeds and config.
    assert cohort_cli.main(shlex.split(resume)[2:]) == 0
    assert engines == []  # each run took its engine
    out = capsys.readouterr().out
    assert "resumed cohort-40…cohort-44 (5 participants): 3 participants simulated (24 trials)" \
        in out
    assert trials_table(broken) == trials_table(whole) and len(trials_table(whole)) == 40
    assert sessions_table(broken) == sessions_table(whole)
    store = Store(broken)
    try:
        assert [c.status for c in cohorts(store)] == ["complete"] and not unfinished(store)
    finally:
        store.close()
    with open_stores([broken]) as opened:
        assert len(opened) == 1  # whole again: the analyses take it


def test_a_half_stored_session_is_dropped_and_run_again(
    tmp_path: Path, engines: list[InProcess], capsys: pytest.CaptureFixture[str]
) -> None:
    """A run killed outright (no chance to mark it): the cohort stays 'running', a session may
    be half-stored; resume drops that session and runs it again."""
    whole, killed = tmp_path / "whole.sqlite", tmp_path / "killed.sqlite"
    engines += [InProcess(), InProcess(fail_after=3), InProcess()]
    assert cohort_cli.main([*COHORT, "--db", str(whole)]) == 0
    assert cohort_cli.main([*COHORT, "--db", str(killed)]) == 2
    with sqlite3.connect(killed) as con:  # as if killed mid-session and before any marking
        con.execute("UPDATE cohorts SET status = 'running', note = ''")
        con.execute("UPDATE sessions SET status = 'running', finished_ns = NULL "
                    "WHERE session = 'cohort-42'")
        con.execute("DELETE FROM trials WHERE session = 'cohort-42' AND trial > 5")
    capsys.readouterr()
    with pytest.raises(ValueError, match="incomplete cohort.*2 stored"), open_stores([killed]):
        pass
    assert cohort_cli.main(["--db", str(killed), "--resume", "--quiet"]) == 0
    assert engines == []
    assert "3 participants simulated (24 trials)" in capsys.readouterr().out
    assert trials_table(killed) == trials_table(whole)
    assert sessions_table(killed) == sessions_table(whole)


def test_resume_refuses_in_one_line(tmp_path: Path, engines: list[InProcess],
                                    capsys: pytest.CaptureFixture[str]) -> None:
    db = tmp_path / "c.sqlite"
    engines += [InProcess(), InProcess()]
    assert cohort_cli.main([*COHORT, "--db", str(db)]) == 0
    capsys.readouterr()
    assert cohort_cli.main(["--db", str(db), "--resume", "--quiet"]) == 2
    assert "holds no incomplete cohort" in capsys.readouterr().err
    assert cohort_cli.main(["--db", str(db), "--resume", "--participants", "3"]) == 2
    assert "leave out --participants" in capsys.readouterr().err
    assert cohort_cli.main(["--db", str(db)]) == 2
    assert "--participants N is required" in capsys.readouterr().err


def test_a_store_from_before_cohorts_were_recorded_reads_as_before(
    tmp_path: Path, engines: list[InProcess]
) -> None:
    db = tmp_path / "old.sqlite"
    engines.append(InProcess())
    assert cohort_cli.main([*COHORT, "--db", str(db)]) == 0
    with sqlite3.connect(db) as con:
        con.execute("DROP TABLE cohorts")  # as an older version wrote it
    with open_stores([db]) as opened:
        _, store = opened[0]
        assert len(store.sessions()) == 5 and cohorts(store) == []


def test_resume_rebuilds_the_cohorts_policy_and_chooses_as_the_first_run(
    tmp_path: Path, engines: list[InProcess], capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from services.store.policies import read_policies

    monkeypatch.setenv("NOD_POLICY_CACHE", str(tmp_path / "cache"))
    paper, other, whole = (tmp_path / f"{n}.sqlite" for n in ("paper", "other", "whole"))
    policy = tmp_path / "bold.toml"
    policy.write_text('kind = "adaptive"\ngaze_levels = ["neutral", "extreme"]\n'
                      'b_stars = [4.54, 6.0]\nu_rs = [2.24]\ntable_people = 2\n'
                      'table_seed = 900000001\n')
    # fail_after=2: the adaptive table's two people are simulated, the cohort stops after two
    engines += [InProcess(fail_after=0), InProcess(), InProcess(fail_after=2), InProcess(),
                InProcess()]
    assert cohort_cli.main([*COHORT, "--db", str(paper), "--policy", "paper"]) == 2
    assert cohort_cli.main(["--db", str(paper), "--resume", "--quiet"]) == 0
    store = Store(paper)
    try:
        assert {p.policy for p in read_policies(store).values()} == {"paper"}
        assert len(read_policies(store)) == 5  # the resumed sessions store it too
    finally:
        store.close()
    assert cohort_cli.main([*COHORT, "--db", str(other), "--policy", str(policy)]) == 2
    assert cohort_cli.main(["--db", str(other), "--resume", "--quiet"]) == 0
    assert cohort_cli.main([*COHORT, "--db", str(whole), "--policy", str(policy)]) == 0

    def chosen(db: Path) -> tuple[list, list]:
        with sqlite3.connect(db) as con:
            return (con.execute("SELECT * FROM policy_trials ORDER BY session, trial").fetchall(),
                    con.execute("SELECT session, trial, outcome, human, robot FROM trials "
                                "ORDER BY session, trial").fetchall())

    resumed, uninterrupted = chosen(other), chosen(whole)
    assert len(resumed[0]) == 5 * 8 and resumed == uninterrupted
    assert {r[3] for r in resumed[0]} == {"neutral", "extreme"}  # the policy did choose
    # A cohort stored before the policy's file was kept with it cannot be rebuilt: refused.
    capsys.readouterr()
    engines += [InProcess(fail_after=2), InProcess()]
    again = tmp_path / "again.sqlite"
    assert cohort_cli.main([*COHORT, "--db", str(again), "--policy", str(policy)]) == 2
    with sqlite3.connect(again) as con:
        con.execute("UPDATE policy_cohorts SET policy_text = NULL, built_on = NULL")
    capsys.readouterr()
    assert cohort_cli.main(["--db", str(again), "--resume", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "ran the policy bold, stored before" in err
