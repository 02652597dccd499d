"""A cut link between two hosts (network namespaces joined by a veth pair): the arm controller
safe-stops within the bound, and resumes when the link returns, without restarting anything."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from datetime import datetime

import pytest

from tests.processes import stop_all

from .conftest import ROOT, wait_for

pytestmark = pytest.mark.integration


def _ip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True)


def _netns_available() -> str | None:
    if os.geteuid() != 0:
        return "needs root to create network namespaces"
    if shutil.which("ip") is None:
        return "needs iproute2 (`ip`)"
    probe = f"nodprobe{os.getpid()}"
    if _ip("netns", "add", probe).returncode != 0:
        return "cannot create network namespaces here"
    _ip("netns", "del", probe)
    return None


SKIP = _netns_available()


class TwoHosts:
    """Host A (router, decision, sim) and host B (actuation), joined by one veth link."""

    def __init__(self, tmp_path) -> None:
        tag = os.getpid() % 200 + 20
        self.a, self.b = f"nodA{os.getpid()}", f"nodB{os.getpid()}"
        self.va, self.vb = f"na{os.getpid()}"[:15], f"nb{os.getpid()}"[:15]
        self.addr_a, self.addr_b = f"10.{tag}.7.1", f"10.{tag}.7.2"
        self.endpoint = f"tcp/{self.addr_a}:7447"
        self.tmp = tmp_path
        self.procs: dict[str, subprocess.Popen] = {}
        for ns in (self.a, self.b):
            assert _ip("netns", "add", ns).returncode == 0
            _ip("-n", ns, "link", "set", "lo", "up")
        assert _ip("link", "add", self.va, "type", "veth", "peer", "name", self.vb).returncode == 0
        for dev, ns, addr in ((self.va, self.a, self.addr_a), (self.vb, self.b, self.addr_b)):
            _ip("link", "set", dev, "netns", ns)
            _ip("-n", ns, "addr", "add", f"{addr}/24", "dev", dev)
            _ip("-n", ns, "link", "set", dev, "up")

    def start(self, ns: str, name: str, *args: str) -> subprocess.Popen:
        log = (self.tmp / f"{name}.log").open("w")
        proc = subprocess.Popen(
            ["ip", "netns", "exec", ns, sys.executable, "-m", "services.cli", *args],
            cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
        )
        self.procs[name] = proc
        return proc

    def link(self, up: bool) -> None:
        _ip("-n", self.b, "link", "set", self.vb, "up" if up else "down")

    def log(self, name: str) -> str:
        return (self.tmp / f"{name}.log").read_text()

    def start_router(self) -> None:
        """The router on host A, once it listens (the services connect to it at start)."""
        self.start(self.a, "router", "router", "--listen", self.endpoint)
        wait_for(lambda: "nod router: listening" in self.log("router"), 30, "the router up")

    def close(self) -> None:
        stop_all(self.procs.values())
        for ns in (self.a, self.b):
            _ip("netns", "del", ns)


def _stamps(log: str, pattern: str) -> list[float]:
    """Wall times (s) of the log lines matching `pattern` (the services log ms timestamps)."""
    out = []
    for line in log.splitlines():
        if re.search(pattern, line):
            stamp = datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f")
            out.append(stamp.timestamp())
    return out


def _arm_clear(log: str) -> bool:
    """The arm controller is up and its last safety line, if any, is a clear.

    Only changes are logged and the controller starts clear, so one whose first check already
    finds fresh inputs never logs "safety clear".
    """
    lines = [line for line in log.splitlines() if "SAFE STOP" in line or "safety clear" in line]
    return "up on rig" in log and (not lines or "safety clear" in lines[-1])


@pytest.mark.skipif(SKIP is not None, reason=SKIP or "")
def test_a_2s_link_cut_safe_stops_the_arm_and_it_resumes_without_a_restart(tmp_path):
    hosts = TwoHosts(tmp_path)
    try:
        hosts.start_router()
        for service in ("decision", "sim"):
            hosts.start(hosts.a, service, service, "--connect", hosts.endpoint)
        arm = hosts.start(hosts.b, "actuation", "actuation", "--connect", hosts.endpoint)
        wait_for(lambda: _arm_clear(hosts.log("actuation")), 30, "the arm up and clear")
        time.sleep(1.0)  # a second of normal running: the cut comes on a steady link
        assert _arm_clear(hosts.log("actuation")), hosts.log("actuation")
        t_cut = time.time()
        hosts.link(False)
        time.sleep(2.0)  # the fault itself: a 2 s cut
        t_back = time.time()
        hosts.link(True)
        wait_for(
            lambda: [t for t in _stamps(hosts.log("actuation"), "safety clear") if t >= t_back],
            10,
            "the arm clear again after the link returned",
        )
        log = hosts.log("actuation")
        stops = [t for t in _stamps(log, "SAFE STOP") if t >= t_cut]
        clears = [t for t in _stamps(log, "safety clear") if t >= t_back]
        assert stops and clears, log[-3000:]
        to_stop, to_clear = stops[0] - t_cut, clears[0] - t_back
        print(f"\nlink cut 2 s: safe stop after {to_stop * 1e3:.0f} ms, "
              f"clear {to_clear * 1e3:.0f} ms after the link returned")
        assert to_stop <= 0.25 + 0.1 + 0.05  # the bound, a tick, the log's ms rounding
        # Back within 2 s: after a 2 s cut TCP's next retransmission (RTO backoff from 200 ms:
        # 0.2, 0.6, 1.4, 3.0 s after the first loss) comes about 1 s after the link returns, so
        # ~1 s is the transport's, not the rig's (1.02 s measured in a clean-clone run).
        assert to_clear <= 2.0
        assert "stale" in log.split("SAFE STOP", 2)[-1].splitlines()[0]
        assert arm.poll() is None and log.count("up on rig") == 1  # no restart
    finally:
        hosts.close()


ONE_TRIAL = """
[[protocol.trials]]
index = 1
mode = "consensus"
option = "red"
gaze_level = "low"
"""


@pytest.mark.skipif(SKIP is not None, reason=SKIP or "")
def test_a_long_cut_mid_trial_interrupts_the_trial_and_it_is_repeated(tmp_path):
    # Once stored as an ordinary trial with a 12 s hole in its samples: now the conductor sees
    # the arm controller's state go silent, interrupts the trial and repeats it.
    from services.store import Store

    params = tmp_path / "one.toml"
    params.write_text(ONE_TRIAL)
    db = tmp_path / "s.sqlite"
    hosts = TwoHosts(tmp_path)
    clock = ["--speed", "2", "--epoch-ns", str(time.time_ns()), "--params", str(params)]
    try:
        hosts.start_router()
        for service in ("decision", "sim"):
            hosts.start(hosts.a, service, service, "--connect", hosts.endpoint, *clock)
        for service in ("actuation", "eyes"):
            hosts.start(hosts.b, service, service, "--connect", hosts.endpoint, *clock)
        conductor = hosts.start(
            hosts.a, "experiment", "experiment", "--connect", hosts.endpoint, *clock,
            "--db", str(db), "--clicks", "10",
        )
        wait_for(lambda: _stamps(hosts.log("experiment"), "trials 1-1"), 40, "all services up")
        wait_for(lambda: "] GO" in hosts.log("experiment"), 40, "trial 1's go")  # under way
        t_cut = time.monotonic()
        hosts.link(False)
        # The conductor breaks the trial during the cut (the arm controller silent)...
        wait_for(lambda: "INTERRUPTED" in hosts.log("experiment"), 30, "trial 1 interrupted")
        # ...which lasts 3 s, the fault itself: a short cut (~0.5 s) leaves the link recovering
        # after the repeat has begun, and a stale gaze breaks that too (a third attempt).
        time.sleep(max(0.0, 3.0 - (time.monotonic() - t_cut)))
        hosts.link(True)
        assert conductor.wait(90) == 0, hosts.log("experiment")[-3000:]
        store = Store(db)
        try:
            session = store.sessions()[-1]["session"]
            broken = store.interruptions(session)
            trials = [t for _, t in store.trials(session)]
        finally:
            store.close()
        assert broken and "silent" in broken[0].reason, (broken, hosts.log("experiment")[-2000:])
        # Repeated and stored whole; a loaded machine may break one more attempt (a late input
        # after the link returns), never fewer, and every attempt broken is on record.
        assert len(trials) == 1 and not trials[0].interrupted
        assert trials[0].attempts == len(broken) + 1 >= 2, (trials[0], broken)
        assert trials[0].robot is not None
    finally:
        hosts.close()
