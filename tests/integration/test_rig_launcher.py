"""A rig as a lab runs it: `nod up` from a rig file, supervision under kill -9, `nod status`,
`nod topic hz`, and `nod run --sim` surviving the death of its services (real processes)."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from functools import partial
from pathlib import Path

import pytest

from services.core import messages as m
from services.core.session import make_config, open_session
from services.store import Store
from tests.processes import run_nod

from .conftest import ROOT, SHORT, free_port, wait_for

pytestmark = pytest.mark.integration


nod = partial(run_nod, timeout=60)
wait_for = partial(wait_for, every_s=0.2)  # the checks run `nod status` or read files


def processes_mentioning(text: str) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
                state = (entry / "stat").read_text().split()[2]
            except OSError:
                continue
            if text in cmd and state != "Z":
                found.append(int(entry.name))
    return found


def status(endpoint: str, rig: str) -> tuple[int, dict]:
    res = nod("status", "--connect", endpoint, "--rig", rig, "--json", "--duration", "1.5")
    return res.returncode, (json.loads(res.stdout) if res.stdout.strip() else {})


@pytest.fixture
def rig_file(tmp_path: Path) -> tuple[Path, str]:
    port = free_port()
    path = tmp_path / "rig.toml"
    path.write_text(
        "[rig]\n"
        'name = "rigx"\n'
        f'router = "tcp/127.0.0.1:{port}"\n'
        "[hosts.control]\nrouter = true\nservices = []\n"
        '[hosts.camera]\nservices = ["vision"]\n'
        '[hosts.arm]\nservices = ["decision", "actuation"]\n'
        '[hosts.eyes]\nservices = ["eyes"]\n'
        '[actuation]\ndriver = "feetech"\nport = "/dev/ttyUSB9"\n'
        '[eyes]\ndriver = "maestro"\nport = "/dev/ttyACM9"\n'
    )
    return path, f"tcp/127.0.0.1:{port}"


def test_nod_up_supervises_the_rig_and_status_and_topic_see_it(rig_file, tmp_path: Path) -> None:
    path, endpoint = rig_file
    up = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "up", str(path), "--sim-hardware",
         "--logs", str(tmp_path / "logs")],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    client = None
    try:
        # Every required service comes up (the sim stands in for the camera).
        doc = wait_for(lambda: (lambda r: r[1] if r[0] == 0 else None)(status(endpoint, "rigx")),
                       40, "every service alive")
        by_name = {s["service"]: s for s in doc["services"]}
        assert {"decision", "actuation", "eyes", "vision"} <= {
            n for n, s in by_name.items() if s["alive"]
        }
        assert by_name["vision"].get("stands_in") == "sim"
        assert all(by_name[s]["restarts"] == 0 for s in ("decision", "actuation", "eyes"))
        # One host, one clock: what is measured is the heartbeat's one-way delay, a few ms at
        # rest and 21 ms once under two CPU burners; seconds would mean a wrong clock.
        assert abs(by_name["decision"]["clock_offset_ms"]) < 200
        assert doc["devices"]["actuation"]["safe_stop"] in (True, False)

        # kill -9 a service: its launcher restarts it within 2 s and says so on rig/event.
        client = open_session(make_config(mode="client", connect=[endpoint]))
        started: list[tuple[float, m.RigEvent]] = []
        beats: list[str] = []

        def on_rig(sample) -> None:
            if str(sample.key_expr) == "nod/rigx/rig/event":
                event = m.decode(m.RigEvent, sample.payload.to_bytes())
                started.append((time.monotonic(), event))
            else:
                beats.append(str(sample.key_expr))

        # One subscriber for events and heartbeats: a heartbeat through it shows the router
        # routes the rig's keys to it. A declaration reaches the router a little later than
        # `declare_subscriber` returns; under load a kill right after it lost the "restarting"
        # event sent at once.
        sub = client.declare_subscriber("nod/rigx/rig/*", on_rig)
        wait_for(lambda: "nod/rigx/rig/status" in beats, 10, "a heartbeat through the subscriber")
        victim = by_name["decision"]["pid"]
        os.kill(victim, signal.SIGKILL)
        t_kill = time.monotonic()
        restarted = wait_for(
            lambda: [t for t, e in started if e.service == "decision" and e.kind == "started"],
            10, "decision restarted",
        )
        assert restarted[0] - t_kill < 2.0, f"restarted after {restarted[0] - t_kill:.2f} s"
        kinds = [e.kind for _, e in started if e.service == "decision"]
        assert kinds[:2] == ["restarting", "started"], kinds
        sub.undeclare()

        # `nod status` shows the restart, with the new process.
        def restarted_once():
            code, d = status(endpoint, "rigx")
            row = {s["service"]: s for s in d.get("services", [])}.get("decision", {})
            fresh = row.get("restarts") == 1 and row.get("pid") != victim
            return d if code == 0 and fresh else None

        wait_for(restarted_once, 20, "status to show the restart")

        # `nod topic hz` on the camera key of the running rig.
        hz = nod("topic", "hz", "nod/rigx/vision/hand", "--connect", endpoint, "--duration", "2")
        assert hz.returncode == 0, hz.stdout + hz.stderr
        rates = [float(w) for line in hz.stdout.splitlines() for w, u in
                 zip(line.split(), line.split()[1:], strict=False) if u == "Hz"]
        assert rates and 20.0 <= rates[-1] <= 40.0, hz.stdout  # the sim camera runs at 30 Hz
    finally:
        if client is not None:
            client.close()
        up.send_signal(signal.SIGTERM)
        out, _ = up.communicate(timeout=30)
    assert up.returncode == 0, out
    assert "every service stopped" in out
    assert not processes_mentioning(endpoint.split("/")[1]), "services left running"


def test_nod_up_refuses_a_bad_rig_file_in_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('[rig]\nrouter = "tcp/127.0.0.1:1"\n[hosts.a]\nservices = ["decision"]\n'
                   '[hosts.b]\nservices = ["decision"]\n')
    res = nod("up", str(bad))
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert "decision already runs on host 'a'" in res.stderr
    res = nod("status", "--rig-file", str(bad))
    assert res.returncode == 2 and "already runs" in res.stderr


def test_a_missing_device_stops_the_rig_at_once_and_says_why(tmp_path: Path) -> None:
    """The arm's port is not there: actuation exits 2 (bad input), is not restarted, its cause is
    on the console, and `nod up` stops every other service and exits 1 — no half rig."""
    port = free_port()
    rig = tmp_path / "rig.toml"
    arm = tmp_path / "arm.toml"
    arm.write_text((Path(ROOT) / "deploy/hardware/arm.example.toml").read_text())
    rig.write_text(
        f'[rig]\nname = "rigm"\nrouter = "tcp/127.0.0.1:{port}"\n'
        '[hosts.lab]\nrouter = true\nservices = ["decision", "actuation", "eyes", "sim"]\n'
        '[actuation]\ndriver = "feetech"\nport = "/dev/ttyNOPE9"\nconfig = "arm.toml"\n'
    )
    t0 = time.monotonic()
    res = nod("up", str(rig), "--logs", str(tmp_path / "logs"))
    took = time.monotonic() - t0
    out = res.stdout + res.stderr
    assert res.returncode == 1, out
    assert "[actuation] gave_up: a configuration error (exit 2)" in out, out
    assert "cannot open serial port /dev/ttyNOPE9" in out, out
    assert "stopping every service" in out and "every service stopped" in out, out
    assert out.count("[actuation] restarting") == 0, out
    assert not processes_mentioning(f"127.0.0.1:{port}"), "services left running"
    print(f"\nnod up with a missing arm port: stopped in {took:.1f} s")


def test_status_exits_1_when_the_rig_is_down(tmp_path: Path) -> None:
    port = free_port()
    router = open_session(make_config(mode="router", listen=[f"tcp/127.0.0.1:{port}"]))
    try:
        code, doc = status(f"tcp/127.0.0.1:{port}", "nobody")
        assert code == 1
        assert set(doc["down"]) == {"decision", "actuation", "eyes", "vision"}
    finally:
        router.close()


def test_run_sim_survives_kill9_of_its_services_and_stores_all_trials(tmp_path: Path) -> None:
    """Kill decision, then actuation, mid-session: each is restarted, the trial under way is
    repeated, and the session still stores its 3 trials, with the restarts recorded."""
    db = tmp_path / "s.sqlite"
    params = tmp_path / "short.toml"
    params.write_text(SHORT)
    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "run", "--sim", "--speed", "4", "--db", str(db),
         "--params", str(params), "--listen", f"tcp/127.0.0.1:{port}", "--stale-ms", "2000"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        def count(sql: str, *args: int) -> int:
            if not db.exists():
                return 0
            with sqlite3.connect(db) as con:
                try:
                    return con.execute(sql, args).fetchone()[0]
                except sqlite3.OperationalError:
                    return 0

        for service, after in (("decision", 1), ("actuation", 2)):
            wait_for(lambda after=after: count("SELECT COUNT(*) FROM trials") >= after, 120,
                     f"trial {after} stored")
            # Into the next trial: its attempt is on record, so the kill breaks a trial under way.
            wait_for(
                lambda n=after + 1: count("SELECT COUNT(*) FROM open_attempts WHERE trial = ?", n),
                60,
                f"trial {after + 1} begun",
            )
            pids = [p for p in processes_mentioning(f"services.cli {service} --connect")
                    if f"127.0.0.1:{port}" in (Path(f"/proc/{p}/cmdline").read_bytes()
                                               .replace(b"\0", b" ").decode())]
            assert len(pids) == 1, pids
            os.kill(pids[0], signal.SIGKILL)
        out, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, out + err
    assert "3 trials of 1 participant(s) stored" in out
    assert "[decision] restarting: killed by SIGKILL" in err
    assert "[actuation] restarting: killed by SIGKILL" in err
    store = Store(db)
    try:
        (session, _), *_ = store.trials(None)
        trials = [t for _, t in store.trials(session)]
        events = store.rig_events(session)
        interruptions = store.interruptions(session)
    finally:
        store.close()
    assert [t.trial for t in trials] == [1, 2, 3]
    assert all(t.robot is not None for t in trials), [
        (t.trial, t.robot, t.human, t.outcome, t.interrupted, t.attempts, t.end_reason)
        for t in trials] + [out[-3000:]] + [err[-3000:]]
    kinds = {(e.service, e.kind) for e in events}
    assert {("decision", "restarting"), ("decision", "started"),
            ("actuation", "restarting"), ("actuation", "started")} <= kinds, events
    # The trials under way when a service died were broken off and repeated.
    assert len(interruptions) >= 1
    assert not processes_mentioning(f"127.0.0.1:{port}")


@pytest.mark.parametrize("service", ["sim", "decision", "actuation"])
def test_sigterm_stops_a_service_within_2_s_when_its_router_is_gone(
    service: str, tmp_path: Path
) -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = open_session(make_config(mode="router", listen=[endpoint]))
    received: list[str] = []
    router.declare_subscriber("nod/gone/**", lambda sample: received.append(str(sample.key_expr)))
    log = (tmp_path / f"{service}.log").open("w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.cli", service, "--connect", endpoint, "--rig", "gone"],
        cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
    )
    try:
        wait_for(lambda: "up on rig" in (tmp_path / f"{service}.log").read_text(), 20,
                 f"{service} up")
        # Publishing into the router (the sim's camera, the arm's state, every heartbeat).
        wait_for(lambda: len(received) >= 3, 20, f"{service} publishing")
        router.close()
        # The fault, not a wait for a condition: a second without the router (the service
        # mid-publish or reconnecting) before the SIGTERM.
        time.sleep(1.0)
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        proc.wait(10)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert took < 2.5, f"{service} took {took:.2f} s to stop after SIGTERM"
