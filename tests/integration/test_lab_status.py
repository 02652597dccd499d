"""`nod lab status`: two rigs' services on one real router, listed by rig from what they send.

Each rig's services are real `Node`s (their liveliness tokens and 1 Hz heartbeats); rig2's
conductor runs a session (its heartbeat carries session, participant and trial) and announces a
trial's phase on experiment/trial. The tool runs as its own process, as a lab screen would.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from collections.abc import Iterator

import pytest

from services.core.node import Node
from services.core.session import Fabric
from services.tools.lab_status import text as lab_text
from tests.processes import stop_all

from .conftest import ROOT, wait_for

pytestmark = pytest.mark.integration
THREE = ("red", "blue", "green")  # one key space: a session over any option set names it


@pytest.fixture
def two_rigs(router, endpoint) -> Iterator[dict[str, Node]]:
    """rig1: decision and actuation, idle; rig2: decision and a conductor in trial 3 of P07."""
    nodes: dict[str, Node] = {}
    rigs = {"rig1": ("decision", "actuation"), "rig2": ("decision", "experiment")}
    for rig, services in rigs.items():
        for service in services:
            node = Node(service, Fabric(rig=rig, connect=(endpoint,)))
            nodes[f"{rig}/{service}"] = node
    conductor = nodes["rig2/experiment"]
    with conductor.lock:
        conductor.activity = {"session": "s-rig2", "participant": "P07", "trial": 3}
    for node in nodes.values():
        node.ready()  # tokens, and the heartbeat thread
    yield nodes
    for node in nodes.values():
        node.close()


def lab_status(endpoint: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "services.cli", "lab", "status", "--connect", endpoint, *args],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )


def test_every_rig_with_its_services_trial_participant_and_clocks(two_rigs, endpoint) -> None:
    done = lab_status(endpoint, "--json", "--duration", "2.5")
    assert done.returncode == 0, done.stderr
    doc = json.loads(done.stdout)
    rigs = {r["rig"]: r for r in doc["rigs"]}
    assert sorted(rigs) == ["rig1", "rig2"]
    assert rigs["rig1"]["alive"] == ["actuation", "decision"]
    assert rigs["rig2"]["alive"] == ["decision", "experiment"]
    assert rigs["rig1"]["participant"] is None and rigs["rig1"]["trial"] is None
    assert (rigs["rig2"]["participant"], rigs["rig2"]["session"], rigs["rig2"]["trial"]) == (
        "P07", "s-rig2", 3)
    for rig in rigs.values():
        for s in rig["services"]:  # every service's heartbeat was heard, its clock compared
            assert s["alive"] and "host" in s, s
            assert abs(s["clock_offset_ms"]) < 1000 and not s["clock_warning"], s
    text = lab_status(endpoint, "--duration", "2.5")  # the same as text, one line per rig
    assert text.returncode == 0, text.stderr
    lines = text.stdout.splitlines()
    assert lines[0].startswith("rig1: 2 alive, no trial, no session, clocks within")
    (rig2,) = [ln for ln in lines if ln.startswith("rig2:")]
    assert "trial 3" in rig2 and "participant P07, session s-rig2" in rig2


def test_watch_follows_the_conductors_events_and_status_lab_is_the_same_tool(
    two_rigs, endpoint,
) -> None:
    watch = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "status", "--lab", "--connect", endpoint,
         "--json", "--watch", "--duration", "0.5"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        rig2 = two_rigs["rig2/experiment"]
        go = rig2.publisher("experiment/trial")
        seen: list[dict] = []

        def phase_go() -> bool:
            go.put(options=THREE, phase="go", trial=4, mode="consensus", option="green",
                   session="s-rig2")
            line = watch.stdout.readline() if watch.stdout else ""
            if line:
                seen.append({r["rig"]: r for r in json.loads(line)["rigs"]})
            return bool(seen) and seen[-1].get("rig2", {}).get("phase") == "go"

        wait_for(phase_go, 20, "rig2's 'go' in the watched lab view")
        assert seen[-1]["rig2"]["trial"] == 4  # the event is fresher than the heartbeat
        assert seen[-1]["rig2"]["options"] == list(THREE)  # and names the session's options
        assert "trial 4 (go), options red,blue,green," in lab_text(
            {"rigs": [seen[-1]["rig2"]]})  # (the paper's red, blue go unsaid)
        go.put(options=THREE, phase="go", trial=4, mode="consensus", session="s-rig2")
        # A later window with no event keeps the last one.
        line = json.loads(watch.stdout.readline() if watch.stdout else "{}")
        assert {r["rig"]: r["phase"] for r in line["rigs"]}["rig2"] == "go"
    finally:
        watch.send_signal(signal.SIGINT)
        try:
            watch.wait(10)
        finally:
            stop_all([watch])
    assert watch.returncode == 0, watch.stderr.read() if watch.stderr else ""


def test_nobody_on_the_network_is_exit_1(router, endpoint) -> None:
    done = lab_status(endpoint, "--duration", "0.5")
    assert done.returncode == 1 and done.stdout.startswith("no rig heard on this network (")


def test_a_running_conductor_tells_the_lab_its_participant_and_trial(tmp_path) -> None:
    """A real `nod run --sim` session: its conductor's heartbeats carry what it runs."""
    import threading

    from services.tools import lab_status

    from .conftest import SHORT, connect_when_listening, free_port

    params = tmp_path / "short.toml"
    params.write_text(SHORT)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "run", "--sim", "--speed", "8", "--rig", "lab3",
         "--participant", "P42", "--params", str(params), "--listen", endpoint, "--stale-ms",
         "2000", "--db", str(tmp_path / "s.sqlite")],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    heard: list[tuple[str, str, int]] = []  # (participant, session, trial) of lab3's conductor
    try:
        session = connect_when_listening(endpoint, alive=lambda: run.poll() is None)
        stop = threading.Event()
        while run.poll() is None and len({t for _, _, t in heard if t}) < 2:
            doc = lab_status.report(lab_status.observe(session, 1.0, stop), 0)
            heard += [(r["participant"], r["session"], r["trial"]) for r in doc["rigs"]
                      if r["rig"] == "lab3" and r["participant"]]
        session.close()
        out, _ = run.communicate(timeout=300)
    finally:
        stop_all([run])
    assert run.returncode == 0, out[-3000:]
    assert heard, "the conductor's heartbeat never named its participant"
    assert {p for p, _, _ in heard} == {"P42"} and all(s for _, s, _ in heard)
    assert len({t for _, _, t in heard if t}) >= 2, heard  # it follows the session's trials
