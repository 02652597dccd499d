"""The lab's Dask cluster as `nod lab secure` says to start it: a real `dask scheduler` and `dask
worker` (separate OS processes, loopback, mutual TLS with the lab's compute certificates; the
worker configured by its `dask.yaml`). `nod cohort` computes on it with the client certificate;
an anonymous client — plain tcp, or a certificate of another CA — cannot connect, so it cannot
submit a task, neither to the scheduler nor to a worker. A scheduler killed mid-cohort (SIGKILL)
leaves the store marked incomplete and `nod cohort` exits with the one command that finishes it;
on a restarted cluster that command completes the cohort with exactly the trials of a run that
was never interrupted."""

from __future__ import annotations

import asyncio
import json
import os
import shlex
import signal
import sqlite3
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from services.lab.secure import main as secure_main
from tests.polling import wait_for
from tests.processes import ROOT, free_port, run_nod, stop_all
from tests.tables import sessions_table, trials_table

pytestmark = pytest.mark.integration


@dataclass
class Cluster:
    address: str
    scheduler: subprocess.Popen
    worker: subprocess.Popen


def _address(scheduler_file: Path) -> str | None:
    try:
        return json.loads(scheduler_file.read_text())["address"]
    except (OSError, ValueError, KeyError):
        return None  # not written yet (or half written)


def _dask(args: list[str], log: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    with log.open("a") as out:
        return subprocess.Popen([sys.executable, "-m", "dask", *args], cwd=ROOT, stdout=out,
                                stderr=subprocess.STDOUT, env=env)


def _joined(tls: Path, address: str) -> bool:
    """A client with the lab's certificate sees one worker thread (the worker has joined)."""
    from services.compute.engine import EngineError, open_engine

    try:
        with open_engine(address, timeout_s=5, tls_dir=tls / "dask" / "client") as engine:
            return engine.threads() == 1
    except EngineError:
        return False


def start_cluster(tls: Path, tmp: Path, port: int = 0) -> Cluster:
    """`dask scheduler` with its certificate flags and a `dask worker` from its dask.yaml, as
    `nod lab secure` prints them, on loopback; returns once the worker has joined."""
    d = tls / "dask"
    sched_file = tmp / f"scheduler-{os.urandom(3).hex()}.json"
    scheduler = _dask(
        ["scheduler", "--host", "tls://127.0.0.1", "--port", str(port),
         "--tls-ca-file", f"{d}/scheduler/ca.pem", "--tls-cert", f"{d}/scheduler/cert.pem",
         "--tls-key", f"{d}/scheduler/key.pem", "--no-dashboard",
         "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(sched_file)],
        tmp / "scheduler.log")
    worker = None
    try:
        address = wait_for(lambda: scheduler.poll() is None and _address(sched_file), 60,
                           "the dask scheduler's address in its scheduler file")
        assert address.startswith("tls://127.0.0.1:")
        worker = _dask(
            ["worker", address, "--nworkers", "1", "--nthreads", "1", "--host", "127.0.0.1",
             "--no-dashboard", "--dashboard-address", "127.0.0.1:0",
             "--local-directory", str(tmp / "worker")],
            tmp / "worker.log", env={**os.environ, "DASK_CONFIG": f"{d}/worker/dask.yaml"})
        wait_for(lambda: worker.poll() is None and _joined(tls, address), 90,
                 "the dask worker to join over TLS")
        return Cluster(address, scheduler, worker)
    except BaseException:
        stop_all([p for p in (worker, scheduler) if p is not None])
        raise


@pytest.fixture(scope="module")
def tls(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("tls")
    assert secure_main(["--out", str(out), "--router-host", "127.0.0.1", "--days", "2"]) == 0
    return out


@pytest.fixture(scope="module")
def cluster(tls: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cluster]:
    c = start_cluster(tls, tmp_path_factory.mktemp("dask"))
    try:
        yield c
    finally:
        stop_all([c.worker, c.scheduler])


def test_nod_cohort_runs_over_mutual_tls_with_the_client_certificate(
    cluster: Cluster, tls: Path, tmp_path: Path
) -> None:
    db = tmp_path / "tls.sqlite"
    res = run_nod("cohort", "--participants", "3", "--seed", "11", "--quiet", "--no-samples",
                  "--db", str(db), "--scheduler", cluster.address,
                  env={**os.environ, "NOD_DASK_TLS": str(tls / "dask" / "client")}, timeout=300)
    assert res.returncode == 0, res.stderr
    assert f"on the cluster at {cluster.address}" in res.stdout
    assert {row[0] for row in trials_table(db)} == {"cohort-11", "cohort-12", "cohort-13"}
    assert len(trials_table(db)) == 3 * 8
    # Without the client certificate: one line saying which flag, no traceback.
    res = run_nod("cohort", "--participants", "1", "--db", str(tmp_path / "no.sqlite"),
                  "--scheduler", cluster.address, timeout=120)
    assert res.returncode == 2 and "needs this machine's client certificate" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr


async def _ask(address: str, connection_args: dict) -> object:
    """Open a comm to a Dask server and ask who it is (any op needs this much)."""
    from distributed.comm import connect

    comm = await connect(address, timeout=5, **connection_args)
    try:
        await comm.write({"op": "identity"})
        return await comm.read()
    finally:
        comm.abort()


def test_an_anonymous_client_can_submit_nothing(
    cluster: Cluster, tls: Path, tmp_path: Path
) -> None:
    from distributed import Client
    from distributed.security import Security

    plain = cluster.address.replace("tls://", "tcp://")
    (worker,) = _workers(cluster, tls)
    # Plain tcp to the scheduler: the connection is dropped before any message; no task.
    with pytest.raises(OSError), Client(plain, timeout=5, set_as_default=False) as client:
        client.submit(os.getuid).result(timeout=5)
    # TLS with the certificate of another CA (the lab's Zenoh monitor, for a lab screen).
    other = tls / "monitor"
    foreign = Security(tls_ca_file=str(other / "ca.pem"), tls_client_cert=str(other / "cert.pem"),
                       tls_client_key=str(other / "key.pem"), require_encryption=True)
    with pytest.raises(OSError), Client(
        cluster.address, timeout=5, set_as_default=False, security=foreign
    ) as client:
        client.submit(os.getuid).result(timeout=5)
    # `nod` itself, pointed there over tcp on loopback (allowed): one line, no traceback.
    res = run_nod("cohort", "--participants", "1", "--db", str(tmp_path / "anon.sqlite"),
                  "--scheduler", plain, timeout=120)
    assert res.returncode == 2 and "cannot reach the Dask scheduler" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr
    # The worker's own port: plain tcp and a foreign certificate get no answer; the lab's
    # client certificate does (so the refusals above are the certificates', not the port's).
    client_args = _client_args(tls / "dask" / "client")
    assert asyncio.run(_ask(worker, client_args))["type"] == "Worker"  # type: ignore[index]
    for address, args in ((worker.replace("tls://", "tcp://"), {}),
                          (worker, foreign.get_connection_args("client"))):
        with pytest.raises(OSError):
            asyncio.run(_ask(address, args))


def _client_args(folder: Path) -> dict:
    from distributed.security import Security

    return Security(tls_ca_file=str(folder / "ca.pem"), tls_client_cert=str(folder / "cert.pem"),
                    tls_client_key=str(folder / "key.pem"),
                    require_encryption=True).get_connection_args("client")


def _workers(cluster: Cluster, tls: Path) -> list[str]:
    from services.compute.engine import open_engine

    with open_engine(cluster.address, tls_dir=tls / "dask" / "client") as engine:
        return list(engine.client.scheduler_info()["workers"])


def _stored(db: Path) -> int:
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as con:
            return con.execute(
                "SELECT COUNT(*) FROM sessions WHERE status = 'complete'").fetchone()[0]
    except sqlite3.Error:
        return 0  # not created yet


def test_a_scheduler_killed_mid_cohort_leaves_it_incomplete_and_resume_completes_it(
    tls: Path, tmp_path: Path
) -> None:
    port = free_port()
    first = start_cluster(tls, tmp_path, port)
    procs = [first.worker, first.scheduler]
    broken, whole = tmp_path / "broken.sqlite", tmp_path / "whole.sqlite"
    client = str(tls / "dask" / "client")
    cohort = ("cohort", "--participants", "60", "--seed", "7", "--quiet", "--no-samples")
    try:
        nod = subprocess.Popen(
            [sys.executable, "-m", "services.cli", *cohort, "--db", str(broken),
             "--scheduler", first.address, "--tls-dir", client],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(nod)
        wait_for(lambda: _stored(broken) >= 5 or nod.poll() is not None, 120,
                 "five participants stored")
        first.scheduler.send_signal(signal.SIGKILL)  # the scheduler dies mid-cohort
        t_kill = time.monotonic()
        out, err = nod.communicate(timeout=120)
        took = time.monotonic() - t_kill
        stored = _stored(broken)
        assert took < 30  # it says so at once (measured 0.3 s), not at some timeout
        assert nod.returncode == 2, (out, err)
        assert 5 <= stored < 60, stored
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in err, err
        assert f"{stored} of its 60 participants are stored" in err
        resume = lines[0].split("finish it with: ", 1)[1]
        assert shlex.split(resume) == ["nod", "cohort", "--db", str(broken), "--resume",
                                       "--scheduler", first.address, "--tls-dir", client,
                                       "--quiet"]
        with sqlite3.connect(broken) as con:
            assert con.execute("SELECT status FROM cohorts").fetchall() == [("incomplete",)]
        # No analysis takes the part for the whole.
        res = run_nod("export", "--db", str(broken), "--out", str(tmp_path / "csv"), timeout=120)
        assert res.returncode != 0 and "incomplete cohort" in res.stderr, res.stderr
        stop_all(procs)
        # The lab restarts its cluster at the same address and runs the printed command.
        second = start_cluster(tls, tmp_path, port)
        procs = [second.worker, second.scheduler]
        assert second.address == first.address
        res = run_nod(*shlex.split(resume)[1:], timeout=300)
        assert res.returncode == 0, res.stderr
        assert f"{60 - stored} participants simulated" in res.stdout
        res = run_nod(*cohort, "--db", str(whole), "--scheduler", second.address,
                      "--tls-dir", client, timeout=300)
        assert res.returncode == 0, res.stderr
        assert len(trials_table(whole)) == 480
        assert trials_table(broken) == trials_table(whole)
        assert sessions_table(broken) == sessions_table(whole)
        with sqlite3.connect(broken) as con:
            assert con.execute("SELECT status FROM cohorts").fetchall() == [("complete",)]
    finally:
        stop_all(procs)
