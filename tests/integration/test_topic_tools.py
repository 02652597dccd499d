"""`nod topic list | echo | hz` as processes on a real router, watching a real 50 Hz stream."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from functools import partial

import pytest

from services.core import messages as m
from services.core.contract import TOPICS
from services.core.node import declare_publisher
from tests.processes import run_nod

from .conftest import ROOT

pytestmark = pytest.mark.integration

RIG = "rig1"
HAND = f"nod/{RIG}/vision/hand"
RATE_HZ = 50.0


_nod = partial(run_nod, timeout=20)


def _pose(i: int) -> bytes:
    x = 0.3 + 0.001 * (i % 100)
    return m.encode(
        m.HandPose(
            seq=i,
            t_ns=time.time_ns(),
            detected=True,
            center=(x, 0.5),
            landmarks=((x - 0.01, 0.5), (x + 0.01, 0.5)),
        )
    )


class Stream:
    """A background thread publishing on one key at a fixed rate (absolute deadlines, no drift)."""

    def __init__(self, session, key: str, rate_hz: float, payload: Callable[[int], bytes]):
        self.sent = 0
        self._stop = threading.Event()
        self._pub = declare_publisher(session, key, TOPICS["vision/hand"].qos)
        self._payload = payload
        self._period = 1.0 / rate_hz
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        due = time.monotonic()
        while not self._stop.is_set():
            self._pub.put(self._payload(self.sent))
            self.sent += 1
            due += self._period
            self._stop.wait(max(0.0, due - time.monotonic()))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self._pub.undeclare()


@pytest.fixture
def stream(client) -> Iterator[Callable[..., Stream]]:
    streams: list[Stream] = []

    def start(payload: Callable[[int], bytes] = _pose, key: str = HAND) -> Stream:
        s = Stream(client, key, RATE_HZ, payload)
        streams.append(s)
        return s

    yield start
    for s in streams:
        s.close()


def test_hz_measures_a_50_hz_stream(endpoint, stream):
    stream()
    run = _nod("topic", "hz", HAND, "--connect", endpoint, "--duration", "2")
    assert run.returncode == 0, run.stdout + run.stderr
    lines = run.stdout.strip().splitlines()
    summary = lines[-1]
    assert summary.startswith(f"summary: {HAND}: "), run.stdout
    rate = float(re.search(r"([\d.]+) Hz", summary).group(1))
    assert abs(rate - RATE_HZ) <= 0.2 * RATE_HZ, summary
    assert re.search(r"min [\d.]+ ms\s+max [\d.]+ ms\s+std [\d.]+ ms", summary), summary
    per_second = [line for line in lines[:-1] if line.endswith(tuple("0123456789"))]
    assert per_second, run.stdout  # at least one `NN.N Hz … window N` line before the summary
    assert all(re.match(r"^\d+\.\d Hz  min ", line) for line in per_second), run.stdout


def test_hz_with_nothing_arriving_exits_1(router, endpoint):
    run = _nod("topic", "hz", "vision/hand", "--connect", endpoint, "--duration", "1")
    assert run.returncode == 1, run.stdout + run.stderr
    assert "nothing arrived on nod/rig1/vision/hand" in run.stderr
    assert "Traceback" not in run.stderr


def test_echo_json_prints_messages_and_one_line_per_garbage_payload(endpoint, stream):
    # Every other sample is garbage: the echo reports each in one line and goes on.
    stream(lambda i: b"\xc1garbage" if i % 2 else _pose(i))
    run = _nod("topic", "echo", "vision/hand", "--json", "--count", "3", "--connect", endpoint,
               "--duration", "8")
    assert run.returncode == 0, run.stdout + run.stderr
    rows = [json.loads(line) for line in run.stdout.splitlines()]
    good = [r for r in rows if "error" not in r]
    bad = [r for r in rows if "error" in r]
    assert len(good) == 3, run.stdout
    for r in good:
        assert r["key"] == HAND and r["v"] == m.SCHEMA_VERSION and r["detected"] is True
        assert set(r) >= {"seq", "t_ns", "center", "landmarks", "source"}
        assert len(r["center"]) == 2 and len(r["landmarks"]) == 2
    assert bad, run.stdout
    assert all(r["key"] == HAND and "hand:" in r["error"] for r in bad)
    assert "Traceback" not in run.stderr


def test_echo_text_is_one_readable_line_per_message(endpoint, stream):
    stream(lambda i: b"junk" if i == 3 else _pose(i))  # only one bad sample, early on
    run = _nod("topic", "echo", HAND, "-n", "5", "--connect", endpoint, "--duration", "8")
    assert run.returncode == 0, run.stdout + run.stderr
    lines = run.stdout.splitlines()
    good = [line for line in lines if "INVALID" not in line]
    assert len(good) == 5, run.stdout
    assert all(
        re.match(rf"^{HAND} #\d+ \d\d:\d\d:\d\d\.\d{{3}} detected=true center=\[", line)
        for line in good
    ), run.stdout


def test_echo_stops_cleanly_on_ctrl_c(endpoint, stream):
    stream()
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "topic", "echo", "vision/hand",
         "--connect", endpoint],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        first = proc.stdout.readline()  # it is printing: it is subscribed and past its setup
        assert first.startswith(HAND), first
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err


def test_list_names_the_keys_seen_and_the_silent_ones(endpoint, stream):
    stream()
    run = _nod("topic", "list", "--connect", endpoint, "--duration", "1.5")
    assert run.returncode == 0, run.stdout + run.stderr
    out = run.stdout
    seen, _, silent = out.partition("silent (in the contract")
    row = next(line for line in seen.splitlines() if line.startswith(HAND))
    assert "HandPose" in row and "vision, sim" in row and " Hz" in row, out
    assert f"nod/{RIG}/safety/estop" in silent and f"nod/{RIG}/vision/layout" in silent, out

    as_json = _nod("topic", "list", "--json", "--connect", endpoint, "--duration", "1.5")
    assert as_json.returncode == 0, as_json.stderr
    report = json.loads(as_json.stdout)
    rows = {r["key"]: r for r in report["keys"]}
    hand = rows[HAND]
    assert hand["seen"] and hand["message"] == "HandPose" and hand["invalid"] == 0
    assert abs(hand["rate_hz"] - RATE_HZ) <= 0.2 * RATE_HZ, hand
    assert rows[f"nod/{RIG}/safety/estop"]["seen"] is False
    assert set(rows) >= {f"nod/{RIG}/{t}" for t, spec in TOPICS.items() if not spec.queried_only}


def test_list_shows_keys_outside_the_contract_and_liveliness(endpoint, client, stream):
    stream(lambda i: b"x", key=f"nod/{RIG}/lab/extra")
    token = client.liveliness().declare_token(f"nod/{RIG}/alive/vision")
    try:
        run = _nod("topic", "list", "--json", "--connect", endpoint, "--duration", "1")
    finally:
        token.undeclare()
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    extra = next(r for r in report["keys"] if r["key"] == f"nod/{RIG}/lab/extra")
    assert extra["seen"] and not extra["in_contract"] and extra["invalid"] == extra["count"]
    assert report["alive"] == ["vision"]


def test_an_unreachable_router_is_one_line_exit_2(endpoint):
    # `endpoint` is a free port: nobody listens there.
    run = _nod("topic", "echo", "vision/hand", "--connect", endpoint, "--duration", "1")
    assert run.returncode == 2, run.stdout + run.stderr
    assert run.stderr.count("\n") == 1 and "cannot open the zenoh session" in run.stderr
    assert ".rs:" not in run.stderr  # zenoh's source locations are trimmed
