"""A service receiving garbage on its keys keeps running and keeps computing."""

import time

import msgpack
import pytest
import zenoh

from services.core import messages as m
from services.core.keys import Keys

from .conftest import Collector, wait_for

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")


def _pose(seq: int, t_ns: int, x: float, y: float) -> bytes:
    lm = tuple((x + dx, y + dy) for dx, dy in ((0.01, 0.0), (-0.01, 0.0), (0.0, 0.01)))
    return m.encode(m.HandPose(seq=seq, t_ns=t_ns, detected=True, center=(x, y), landmarks=lm))


def test_decision_survives_garbage_and_keeps_publishing(client, spawn):
    proc = spawn("decision")
    z_r = Collector(client, KEYS.topic("decision/z_r"), m.Opinions)
    z_h = Collector(client, KEYS.topic("decision/z_h"), m.Observed)
    # BLOCK: the 100 kB garbage must not make the test's own valid poses droppable en route.
    hand = client.declare_publisher(
        KEYS.topic("vision/hand"), congestion_control=zenoh.CongestionControl.BLOCK
    )
    trial = client.declare_publisher(KEYS.topic("experiment/trial"))
    t0 = time.time_ns()
    wait_for(lambda: (hand.put(_pose(0, t0, 0.5, 0.85)), bool(z_r.items))[1], 20, "decision up")

    garbage = [
        b"",
        b"\xc1\xff",
        b"not msgpack at all",
        msgpack.packb([1, 2, 3]),
        msgpack.packb(
            {
                "v": m.SCHEMA_VERSION,
                "seq": 1,
                "t_ns": 1,
                "detected": True,
                "center": [0.5, float("nan")],
                "landmarks": [[0.5, 0.5]],
            }
        ),
        msgpack.packb(
            {
                "v": m.SCHEMA_VERSION,
                "seq": 1,
                "t_ns": 1,
                "detected": True,
                "center": [0.5, 0.5],
                "landmarks": [[0.5]],
            }
        ),
        msgpack.packb({"v": 7, "seq": 1, "t_ns": 1}),
        b"\x00" * 100_000,
    ]
    for payload in garbage:
        hand.put(payload)
        trial.put(payload)
    trial.put(m.encode(m.TrialEvent(seq=0, t_ns=t0 + 1, phase="go", trial=1, mode="dissensus",
                                    options=("red", "blue"))))

    # A hand heading for red after the garbage: decision must still answer every pose.
    n_before = len(z_r.items)
    for i in range(1, 31):  # stamped now: decision refuses poses from the future
        hand.put(_pose(i, time.time_ns(), 0.5 + 0.008 * i, 0.85 - 0.01 * i))
        time.sleep(0.01)
    # Every pose is answered; decision's outputs use drop congestion control (the control loop
    # never waits for a slow reader), so on a saturated machine the router may shed one or two
    # on the way to this test's client: wait for the last pose's answer, then count.
    try:
        wait_for(lambda: any(x.src_seq == 30 for x in z_r.messages), 10, "the last pose's answer")
    except AssertionError as exc:
        seen = sorted(msg.src_seq for msg in z_r.messages[n_before:])
        raise AssertionError(f"{exc}; answered {seen}; log:\n{proc.log_path.read_text()}") from None
    answered = {msg.src_seq for msg in z_r.messages[n_before:]}
    assert len(answered & set(range(1, 31))) >= 28, (sorted(answered), proc.log_path.read_text())
    assert proc.poll() is None, "decision died on garbage"
    last_zh = z_h.messages[-1]
    assert last_zh.signed > 0  # the human heads for red
    assert z_r.messages[-1].signed < 0  # dissensus trial: the robot opposes
    log = proc.log_path.read_text()
    assert log.count("dropped bad message") >= 2 * len(garbage) - 2
    assert "vision/hand" in log and "experiment/trial" in log
