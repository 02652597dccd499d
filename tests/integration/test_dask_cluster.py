"""`nod cohort --scheduler` on a real Dask cluster: `dask scheduler` and `dask worker` as separate
OS processes on loopback (free ports, the address read from the scheduler file), giving the same
stored outcomes as the embedded local cluster for the same seed."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from services.compute.engine import EngineError, open_engine
from tests.polling import wait_for
from tests.processes import ROOT, run_nod, stop_all

pytestmark = pytest.mark.integration


def _dask(*args: str, log: Path) -> subprocess.Popen:
    with log.open("w") as out:
        return subprocess.Popen([sys.executable, "-m", "dask", *args], cwd=ROOT,
                                stdout=out, stderr=subprocess.STDOUT)


def _address(scheduler_file: Path) -> str | None:
    try:
        return json.loads(scheduler_file.read_text())["address"]
    except (OSError, ValueError, KeyError):
        return None  # not written yet (or half written)


@pytest.fixture(scope="module")
def scheduler(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    """A `dask scheduler` on a free loopback port, with no worker yet."""
    tmp = tmp_path_factory.mktemp("dask")
    sched_file = tmp / "scheduler.json"
    proc = _dask("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                 "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(sched_file),
                 log=tmp / "scheduler.log")
    try:
        address = wait_for(lambda: proc.poll() is None and _address(sched_file), 60,
                           "the dask scheduler's address in its scheduler file")
        yield address, tmp
    finally:
        stop_all([proc])


@pytest.fixture(scope="module")
def cluster(scheduler: tuple[str, Path]) -> Iterator[str]:
    """The scheduler with one `dask worker` (one process, one thread)."""
    address, tmp = scheduler
    proc = _dask("worker", address, "--nworkers", "1", "--nthreads", "1", "--host", "127.0.0.1",
                 "--no-dashboard", "--local-directory", str(tmp / "worker"),
                 log=tmp / "worker.log")
    try:
        def joined() -> bool:
            with open_engine(address, timeout_s=5) as engine:
                return engine.threads() == 1
        wait_for(lambda: proc.poll() is None and _joins(joined), 90, "the dask worker to join")
        yield address
    finally:
        stop_all([proc])


def _joins(check) -> bool:
    try:
        return check()
    except EngineError:
        return False


def test_a_scheduler_without_workers_is_one_clear_line(scheduler: tuple[str, Path]) -> None:
    address, _ = scheduler
    with pytest.raises(EngineError, match="no Dask worker joined") as err, \
            open_engine(address, timeout_s=1):
        pass
    assert f"dask worker {address}" in str(err.value) and "\n" not in str(err.value)


def _outcomes(db: Path) -> list[tuple]:
    with sqlite3.connect(db) as con:
        return con.execute(
            "SELECT s.seed, t.trial, t.outcome, t.human, t.robot, t.switches FROM trials t "
            "JOIN sessions s ON s.session = t.session ORDER BY s.seed, t.trial").fetchall()


def test_nod_cohort_on_the_cluster_stores_what_the_local_engine_stores(
    cluster: str, tmp_path: Path
) -> None:
    remote, local = tmp_path / "remote.sqlite", tmp_path / "local.sqlite"
    common = ("cohort", "--participants", "4", "--seed", "21", "--quiet", "--no-samples")
    res = run_nod(*common, "--db", str(remote), "--scheduler", cluster, timeout=300)
    assert res.returncode == 0, res.stderr
    assert f"on the cluster at {cluster}" in res.stdout
    res = run_nod(*common, "--db", str(local), "--workers", "2", timeout=300)
    assert res.returncode == 0, res.stderr
    assert "local cluster of 2 workers" in res.stdout
    got = _outcomes(remote)
    assert len(got) == 4 * 8 and {row[0] for row in got} == {21, 22, 23, 24}
    assert got == _outcomes(local)
