"""Bounded intake on the wire: a message over its key's limit never reaches a subscriber, and a
burst of large messages from other processes on the host leaves the router and a service as
large as they were (zenoh's shared-memory transport is off)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from services.core import messages as m
from services.core.keys import Keys
from services.core.session import make_config, open_session
from tests.processes import ROOT, stop_all

from .conftest import Collector, connect_when_listening, wait_for

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")
MB = 1024  # kB
BOUND_KB = 20 * MB  # what a burst may leave behind in a process


def bare(mode: str, endpoint: str) -> zenoh.Session:
    """A session with zenoh's own defaults (no limits, shared memory on): any peer's."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("listen/endpoints" if mode == "router" else "connect/endpoints",
                      json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def _rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


def _gaze(seq: int) -> bytes:
    return m.encode(m.GazeMsg(seq=seq, t_ns=time.time_ns(), level="low"))


def _only_small_ones_arrive(sender: zenoh.Session, receiver: zenoh.Session) -> None:
    """60 kB on three keys with smaller limits is dropped; a frame-sized key lets it by."""
    keys = ("eyes/cmd", "vision/hand", "safety/estop")
    raw: list[tuple[str, int]] = []
    sub = receiver.declare_subscriber(
        KEYS.all, lambda s: raw.append((str(s.key_expr), len(s.payload)))
    )
    pubs = {
        k: sender.declare_publisher(
            KEYS.topic(k), congestion_control=zenoh.CongestionControl.BLOCK  # none lost to load
        )
        for k in (*keys, "vision/frame")
    }
    # The subscriber's route is up for every key before anything is sent (a loaded machine
    # takes longer than any fixed pause).
    wait_for(lambda: all(p.matching_status.matching for p in pubs.values()), 10,
             "the receiver's subscription at the sender")
    for i in range(3):
        for k in keys:
            pubs[k].put(b"\x00" * 60_000)
        pubs["eyes/cmd"].put(_gaze(i))
    pubs["vision/frame"].put(b"\x00" * 60_000)
    # Order holds per publisher: once the small gaze and the frame arrived, so would have the rest.
    wait_for(lambda: sum(1 for k, n in raw if n < 100) == 3, 5, "the small gazes")
    wait_for(lambda: any(k.endswith("vision/frame") for k, _ in raw), 5, "the 60 kB frame")
    big = [(k, n) for k, n in raw if n >= 60_000 and not k.endswith("vision/frame")]
    assert big == [], big
    sub.undeclare()


def test_the_rig_router_drops_a_message_over_its_keys_limit(router, endpoint):
    sender, receiver = bare("client", endpoint), bare("client", endpoint)
    try:
        _only_small_ones_arrive(sender, receiver)
    finally:
        sender.close()
        receiver.close()


def test_a_rig_session_drops_it_behind_a_router_without_limits(endpoint):
    plain = bare("router", endpoint)  # e.g. a zenohd with its defaults
    sender = bare("client", endpoint)
    receiver = open_session(make_config(mode="client", connect=[endpoint]))
    try:
        _only_small_ones_arrive(sender, receiver)
    finally:
        for s in (receiver, sender, plain):
            s.close()


def test_a_burst_of_large_messages_leaves_router_and_eyes_within_20_mb(endpoint, spawn, tmp_path):
    log = (tmp_path / "router.log").open("w")
    router = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "router", "--listen", endpoint],
        cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
    )
    attackers: list[zenoh.Session] = []
    client = None
    try:
        client = connect_when_listening(endpoint, 20, alive=lambda: router.poll() is None)
        eyes = spawn("eyes", "--driver", "sim")
        states = Collector(client, KEYS.topic("eyes/state"), m.EyesStateMsg)
        wait_for(lambda: len(states.items) > 20, 30, "the eyes publishing their state")
        # Three senders with zenoh's defaults: before, each one's 16 MiB shared-memory pool
        # stayed mapped in the router and in the eyes (here +80 MB and +72 MB for good).
        attackers = [bare("client", endpoint) for _ in range(3)]
        keys = ("eyes/cmd", "safety/estop", "safety/release")
        pubs = [
            a.declare_publisher(KEYS.topic(k), congestion_control=zenoh.CongestionControl.BLOCK)
            for a in attackers for k in keys
        ]
        time.sleep(0.3)
        before = {"router": _rss_kb(router.pid), "eyes": _rss_kb(eyes.pid)}
        for size in (60_000, 200_000):
            payload = b"\x00" * size
            for _ in range(150):
                for pub in pubs:
                    pub.put(payload)  # 150 × 9 = 1350 of each size: 350 MB in all
        n = len(states.items)
        wait_for(lambda: len(states.items) > n + 10, 10, "the eyes still publishing")

        def growth() -> dict[str, int]:
            return {"router": _rss_kb(router.pid) - before["router"],
                    "eyes": _rss_kb(eyes.pid) - before["eyes"]}

        try:  # freed memory may take a moment to leave a process: poll, never a fixed sleep
            wait_for(lambda: max(growth().values()) <= BOUND_KB, 5, "memory back within 20 MB")
        except AssertionError as exc:
            raise AssertionError(f"RSS growth after the burst (kB): {growth()}") from exc
        print(f"\nRSS before the burst (kB) {before}, growth after it {growth()}")
        assert router.poll() is None and eyes.poll() is None
    finally:
        for a in attackers:
            a.close()
        if client is not None:
            client.close()
        stop_all([router])
        log.close()
