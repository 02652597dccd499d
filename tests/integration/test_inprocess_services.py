"""Service shells built from typed config, in this process, on a real loopback router.

Each test opens the services' `Node`s from a `Fabric` (no argparse), so it runs in well under a
second while still going through real zenoh sessions, the contract's QoS and the codecs.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from services.core import messages as m
from services.core.node import Node
from services.core.session import Fabric
from services.decision.service import DecisionService
from services.eyes.service import EyesService
from services.eyes.servos import SimServoDriver
from services.model.decision import DecisionModel
from services.model.safety import SafetyParams
from tests.integration.conftest import Collector, wait_for

pytestmark = pytest.mark.integration


def _stream(n: int, hz: float = 30.0) -> list[tuple[int, list[tuple[float, float]]]]:
    rng = np.random.default_rng(4)
    x, y, out = 0.45, 0.86, []
    for i in range(n):
        x, y = x + 0.2 / hz, y - 0.3 / hz
        pts = [(float(x + rng.normal(0, 2e-3)), float(y + rng.normal(0, 2e-3))) for _ in range(21)]
        out.append((1_000_000_000 + round(i * 1e9 / hz), pts))
    return out


def test_live_decision_publishes_exactly_the_models_values(router, endpoint, client):
    fabric = Fabric(connect=(endpoint,))
    decision = Node("decision", fabric)
    DecisionService(decision, DecisionModel())
    decision.ready()
    camera = Node("sim", fabric)
    z_r = Collector(client, camera.keys.topic("decision/z_r"), m.Scalar)
    b_r = Collector(client, camera.keys.topic("decision/b_r"), m.Scalar)
    conductor = Node("experiment", fabric)
    trial = conductor.publisher("experiment/trial")
    hands = camera.publisher("vision/hand")
    try:
        wait_for(lambda: hands._pub.matching_status.matching, 5.0, "decision subscribed")
        trial.put(phase="go", trial=5, mode="consensus", option="red")
        wait_for(lambda: decision.received["experiment/trial"] == 1, 5.0, "the trial event")
        stream = _stream(60)
        for t_ns, pts in stream:
            center = (sum(p[0] for p in pts) / 21, sum(p[1] for p in pts) / 21)
            hands.put(t_ns=t_ns, detected=True, center=center, landmarks=tuple(pts))
            time.sleep(0.004)  # a camera paces its poses; a burst may be dropped by design
        wait_for(lambda: len(z_r.messages) == len(stream), 5.0, "one z_r per pose")
        reference = DecisionModel()
        reference.reset("consensus", "red")
        expected = [reference.on_hand(t, pts) for t, pts in stream]
        got = sorted(z_r.messages, key=lambda msg: msg.src_seq)
        assert [msg.value for msg in got] == [e.z_r for e in expected]
        wait_for(lambda: len(b_r.messages) == len(stream), 5.0, "one b_r per pose")
        assert sorted(b.value for b in b_r.messages) == sorted(e.b_r for e in expected)
        assert expected[-1].b_r > 0  # consensus toward red did run eq 6
    finally:
        for node in (decision, camera, conductor):
            node.close()


def test_eyes_follow_gaze_commands_and_go_neutral_when_they_stop(router, endpoint, client):
    fabric = Fabric(connect=(endpoint,))
    driver = SimServoDriver()
    driver.connect()
    eyes = Node("eyes", fabric)
    safety = SafetyParams(stale_ms=150.0, require_alive=("experiment",))
    service = EyesService(eyes, driver, safety)
    runner = threading.Thread(target=eyes.run, daemon=True)
    runner.start()
    conductor = Node("experiment", fabric)
    gaze = conductor.publisher("eyes/cmd")
    conductor.ready()  # the eyes require the conductor's liveliness
    state = Collector(client, eyes.keys.topic("eyes/state"), m.EyesStateMsg)
    try:
        wait_for(lambda: gaze._pub.matching_status.matching, 5.0, "eyes subscribed")
        stop = threading.Event()

        def keep_alive() -> None:  # the conductor's keep-alive of a gesture pose
            while not stop.wait(0.03):
                gaze.put(yaw=1.4, pitch=0.0, level="minimal", gesture=True, trial=4)

        pump = threading.Thread(target=keep_alive, daemon=True)
        pump.start()
        wait_for(lambda: service.gaze.yaw == 1.4 and not service.safe_stop, 5.0, "the pose")
        wait_for(lambda: driver.last is not None and driver.last.angles_deg[0] > 160, 2.0, "servos")
        stop.set()
        pump.join()
        wait_for(lambda: service.safe_stop, 2.0, "a safe stop once the gaze goes stale")
        wait_for(lambda: driver.last.angles_deg == (90.0, 90.0, 90.0, 90.0), 2.0, "neutral")
        assert any(s.safe_stop and "gaze stale" in s.safety_reason for s in state.messages)
    finally:
        eyes.stop.set()
        runner.join(5)
        conductor.close()
