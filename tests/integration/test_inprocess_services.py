"""Service shells built from typed config, in this process, on a real loopback router.

Each test opens the services' `Node`s from a `Fabric` (no argparse), so it runs in well under a
second while still going through real zenoh sessions, the contract's QoS and the codecs.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
import pytest

from services.core import messages as m
from services.core.node import Node, TopicPublisher
from services.core.session import Fabric
from services.decision.service import DecisionService
from services.eyes.service import EyesService
from services.eyes.servos import SimServoDriver
from services.model.decision import DecisionModel, OptionsDecision
from services.model.geometry import COLOURS
from services.model.params import NodConfig
from services.model.policy import PolicySettings, decision_for
from services.model.safety import SafetyParams
from services.model.schedule import OptionsSchedule
from tests.integration.conftest import Collector, wait_for

pytestmark = pytest.mark.integration


@contextmanager
def _running(node: Node, pump: Callable[[], None], every_s: float) -> Iterator[None]:
    """The node's loop on a thread, and `pump()` every `every_s` on another (the inputs its
    watchdog requires); both stopped and joined after, whatever the test did."""
    stop = threading.Event()

    def pumping() -> None:
        while not stop.wait(every_s):
            pump()

    runner = threading.Thread(target=node.run, daemon=True)
    pumper = threading.Thread(target=pumping, daemon=True)
    runner.start()
    pumper.start()
    try:
        yield
    finally:
        stop.set()
        pumper.join()
        node.stop.set()
        runner.join(5)


def _assert_the_pace_holds_and_an_estop_shows(
    state: Collector, estop: TopicPublisher, estop_id: str, key: str
) -> None:
    """With a device's fault on its state key: the key keeps its 50 Hz (the I/O is on the
    driver's thread), the fault stays on it, and an e-stop shows on it within its 100 ms bound
    (plus the test's own polling)."""
    n = len(state.messages)
    time.sleep(1.0)  # a rate's window, not a wait: the state keeps its pace meanwhile
    assert len(state.messages) - n >= 35  # ≈ 50 Hz while the device is gone
    assert any(s.fault for s in state.messages[-5:])
    t0 = time.monotonic()
    estop.put(engaged=True, reason="test", source="test", id=estop_id)
    wait_for(
        lambda: any(s.estop_id == estop_id and s.safe_stop for s in state.messages),
        2.0,
        f"the e-stop on {key}",
    )
    assert time.monotonic() - t0 < 0.1 + 0.05
    assert any(s.fault for s in state.messages[-5:])


def _stream(n: int, hz: float = 30.0) -> list[tuple[int, list[tuple[float, float]]]]:
    rng = np.random.default_rng(4)
    x, y, out = 0.45, 0.86, []
    for i in range(n):
        x, y = x + 0.2 / hz, y - 0.3 / hz
        pts = [(float(x + rng.normal(0, 2e-3)), float(y + rng.normal(0, 2e-3))) for _ in range(21)]
        out.append((1_000_000_000 + round(i * 1e9 / hz), pts))
    return out


@pytest.mark.parametrize("n_options", [2, 3])
def test_live_decision_publishes_exactly_the_models_values(router, endpoint, client, n_options):
    # One decision service on one key space whatever the number of options: the paper's kernel
    # at two (its signed z as (z, -z)), the N-option engine's vectors at three, each value the
    # engine's.
    cfg = NodConfig()
    names = OptionsSchedule.default(n_options).names
    fabric = Fabric(connect=(endpoint,))
    decision = Node("decision", fabric)
    DecisionService(decision, cfg, names)
    decision.ready()
    camera = Node("sim", fabric)
    reference: DecisionModel | OptionsDecision
    if n_options == 2:
        reference = DecisionModel(cfg.decision, cfg.layout)
        reference.reset("consensus", "red")
    else:
        reference = OptionsDecision(cfg.table(n_options), cfg.decision)
        reference.reset("consensus", 0)
    z_r = Collector(client, camera.keys.topic("decision/z_r"), m.Opinions)
    b_r = Collector(client, camera.keys.topic("decision/b_r"), m.Opinions)
    conductor = Node("experiment", fabric)
    trial_key = "experiment/trial"
    trial = conductor.publisher(trial_key)
    hands = camera.publisher("vision/hand")
    try:
        wait_for(lambda: hands._pub.matching_status.matching, 5.0, "decision subscribed")
        trial.put(phase="go", trial=5, mode="consensus", option="red", options=names)
        wait_for(lambda: decision.received[trial_key] == 1, 5.0, "the trial event")
        stream = _stream(60)
        for i, (t_ns, pts) in enumerate(stream):
            center = (sum(p[0] for p in pts) / 21, sum(p[1] for p in pts) / 21)
            hands.put(t_ns=t_ns, detected=True, center=center, landmarks=tuple(pts))
            # Lock step: the next pose once this one's z_r is out. A burst may be dropped by
            # design (the intake keeps up with a camera, not with a stalled one), and a loaded
            # host stalls whatever pace a sleep here sets.
            wait_for(lambda n=i + 1: len(z_r.messages) >= n, 30.0, f"z_r of pose {i + 1}")
        expected = [reference.on_hand(t, pts) for t, pts in stream]

        def values(x: object) -> object:  # the paper's z as (z, -z), a vector as its tuple
            return tuple(x.tolist()) if isinstance(x, np.ndarray) else (x, -x)  # type: ignore[operator]

        def got(msg: m.Opinions) -> object:
            assert msg.options == names
            return msg.values

        received = sorted(z_r.messages, key=lambda msg: msg.src_seq)
        assert [got(msg) for msg in received] == [values(e.z_r) for e in expected]
        wait_for(lambda: len(b_r.messages) == len(stream), 5.0, "one b_r per pose")
        by_seq = sorted(b_r.messages, key=lambda msg: msg.src_seq)
        assert [got(msg) for msg in by_seq] == [values(e.b_r) for e in expected]
        last = expected[-1].b_r
        assert (last if n_options == 2 else last[0]) > 0  # consensus toward O did run eq 6
    finally:
        for node in (decision, camera, conductor):
            node.close()


@pytest.mark.parametrize("inside", [True, False], ids=["inside", "outside the envelope"])
def test_decision_runs_a_trial_on_its_policys_settings_and_refuses_settings_outside(
        router, endpoint, client, inside):
    # The conductor's policy sends trial 5's b* and u_r before its "go": the service's values
    # are then exactly those of the kernel on those settings. Settings outside the params
    # file's [policy] envelope are refused (counted as dropped): the trial runs on the file's.
    cfg = NodConfig()
    settings = PolicySettings(6.0 if inside else 9.0, "extreme", 1.8)
    fabric = Fabric(connect=(endpoint,))
    decision = Node("decision", fabric)
    DecisionService(decision, cfg, COLOURS)
    decision.ready()
    camera, conductor = Node("sim", fabric), Node("experiment", fabric)
    z_r = Collector(client, camera.keys.topic("decision/z_r"), m.Opinions)
    trial = conductor.publisher("experiment/trial")
    policy = conductor.publisher("experiment/policy")
    hands = camera.publisher("vision/hand")
    try:
        wait_for(lambda: hands._pub.matching_status.matching, 5.0, "decision subscribed")
        policy.put(session="s", trial=5, policy="mine", b_star=settings.b_star,
                   gaze_level=settings.gaze_level, u_r=settings.u_r)
        wait_for(lambda: decision.received["experiment/policy"] == 1, 5.0, "the settings")
        assert (decision.bad["experiment/policy"] == 0) == inside
        trial.put(phase="go", trial=5, mode="consensus", option="red", options=COLOURS)
        wait_for(lambda: decision.received["experiment/trial"] == 1, 5.0, "the trial event")
        reference = DecisionModel(decision_for(cfg.decision, settings) if inside
                                  else cfg.decision, cfg.layout)
        reference.reset("consensus", "red")
        stream = _stream(45)
        for i, (t_ns, pts) in enumerate(stream):
            center = (sum(p[0] for p in pts) / 21, sum(p[1] for p in pts) / 21)
            hands.put(t_ns=t_ns, detected=True, center=center, landmarks=tuple(pts))
            wait_for(lambda n=i + 1: len(z_r.messages) >= n, 30.0, f"z_r of pose {i + 1}")
        expected = [reference.on_hand(t, pts).z_r for t, pts in stream]
        got = [msg.values[0] for msg in sorted(z_r.messages, key=lambda msg: msg.src_seq)]
        assert got == expected
        paper = DecisionModel(cfg.decision, cfg.layout)
        paper.reset("consensus", "red")
        assert ([paper.on_hand(t, pts).z_r for t, pts in stream] != expected) == inside
    finally:
        for node in (decision, camera, conductor):
            node.close()


def test_eyes_follow_gaze_commands_and_go_neutral_when_they_stop(router, endpoint, client):
    fabric = Fabric(connect=(endpoint,))
    driver = SimServoDriver()
    driver.connect()
    eyes = Node("eyes", fabric)
    safety = SafetyParams(stale_ms=150.0, require_alive=("experiment",))
    service = EyesService(eyes, driver, safety, None)
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
        wait_for(
            lambda: any(s.safe_stop and "gaze stale" in s.safety_reason for s in state.messages),
            2.0,
            "the stale gaze on eyes/state",
        )
    finally:
        eyes.stop.set()
        runner.join(5)
        conductor.close()


def test_a_silent_arduino_never_holds_up_the_eyes_safety(router, endpoint, client):
    # The board goes silent (and a reopen would wait 3 s for its boot): the serial I/O runs on
    # the driver's own thread, so the state key keeps its 50 Hz and an e-stop shows within 100 ms.
    from services.eyes.arduino import ArduinoEyesConfig, ArduinoServoDriver
    from tests.emulators.arduino_emulator import ArduinoEyesEmulator
    from tests.emulators.links import LINK

    with ArduinoEyesEmulator() as board:
        driver = ArduinoServoDriver(board.port, ArduinoEyesConfig(boot_wait_s=3.0, link=LINK))
        driver.connect()
        fabric = Fabric(connect=(endpoint,))
        eyes = Node("eyes", fabric)
        safety = SafetyParams(stale_ms=250.0, require_alive=("experiment",))
        EyesService(eyes, driver, safety, None)
        conductor = Node("experiment", fabric)
        gaze = conductor.publisher("eyes/cmd")
        conductor.ready()
        operator = Node("estop", fabric)
        estop = operator.publisher("safety/estop")
        state = Collector(client, eyes.keys.topic("eyes/state"), m.EyesStateMsg)
        try:
            with _running(eyes, lambda: gaze.put(yaw=0.5, pitch=0.0, level="low", trial=5), 0.03):
                wait_for(lambda: any(not s.safe_stop for s in state.messages[-3:]), 5.0, "eyes up")
                board.silent = True
                board.unplug()  # gone: the driver reopens with a 3 s boot wait, on its own thread
                wait_for(lambda: any(s.fault for s in state.messages[-3:]), 5.0,
                         "the board's fault")
                _assert_the_pace_holds_and_an_estop_shows(state, estop, "e1", "eyes/state")
        finally:
            conductor.close()
            driver.disconnect()
            operator.close()
            driver.disconnect()


def test_a_silent_arm_bus_never_holds_up_the_actuation_safety(router, endpoint, client):
    # The servos stop answering mid-trial: the bus I/O runs on the arm driver's own thread, so
    # actuation's state key keeps its pace and an e-stop shows within 100 ms.
    from services.actuation.arm_path import ArmPoses
    from services.actuation.feetech_arm import FeetechArm, FeetechArmConfig
    from services.actuation.service import ActuationService
    from services.actuation.threaded_arm import ThreadedArm
    from tests.emulators.feetech_emulator import FeetechBusEmulator
    from tests.emulators.links import LINK

    poses = ArmPoses((2048, 2048), (2448, 2148), (2448, 2348), (1648, 2148), (1648, 2348))
    cfg = FeetechArmConfig(ids=(1, 2), poll_interval_s=0.05, poses=poses, link=LINK)
    with FeetechBusEmulator({1: 2048, 2: 2048}) as bus:
        arm = ThreadedArm(FeetechArm(bus.port, cfg, NodConfig().layout))
        arm.connect()
        fabric = Fabric(connect=(endpoint,))
        node = Node("actuation", fabric)
        safety = SafetyParams(stale_ms=250.0, require_alive=("decision",))
        ActuationService(node, NodConfig(), arm, safety, None)
        peer = Node("decision", fabric)
        z_r = peer.publisher("decision/z_r")
        peer.ready()
        camera = Node("sim", fabric)
        hands = camera.publisher("vision/hand")
        operator = Node("estop", fabric)
        estop = operator.publisher("safety/estop")
        state = Collector(client, node.keys.topic("actuation/state"), m.ArmStateMsg)

        def inputs() -> None:
            z_r.put(src_seq=0, **m.signed_fields(0.3))
            hands.put(detected=True, center=(0.5, 0.85), landmarks=((0.5, 0.85),))

        try:
            with _running(node, inputs, 0.02):
                wait_for(lambda: any(not s.safe_stop for s in state.messages[-3:]), 5.0, "arm up")
                bus.silent = True  # every read now costs the link's timeouts
                wait_for(lambda: any(s.fault for s in state.messages[-3:]), 5.0,
                         "the bus's fault")
                _assert_the_pace_holds_and_an_estop_shows(state, estop, "a1", "actuation/state")
        finally:
            for other in (peer, camera, operator):
                other.close()
            arm.disconnect()


@pytest.mark.parametrize("n_options", [2, 3])
def test_an_arm_fault_is_a_safe_stop_whatever_the_number_of_options(
    router, endpoint, client, n_options
):
    # The arm reports a device fault mid-trial (the sim arm's stand-in for a silent bus): the
    # one actuation service stops on it, says so on actuation/state for any number of options
    # (the N-option copy never told its watchdog), and clears once the device is healthy.
    from services.actuation.service import ActuationService, ArmChoice, arm_seam

    cfg = NodConfig()
    names = OptionsSchedule.default(n_options).names
    fabric = Fabric(connect=(endpoint,))
    node = Node("actuation", fabric)
    arm = arm_seam(names).make_arm(ArmChoice("sim"), cfg, names, node.clock.now_ns() * 1e-9)
    arm.connect()
    safety = SafetyParams(stale_ms=500.0, require_alive=("decision",))
    ActuationService(node, cfg, arm, safety, None, names)
    peer = Node("decision", fabric)
    z_r = peer.publisher("decision/z_r")
    peer.ready()
    camera = Node("sim", fabric)
    hands = camera.publisher("vision/hand")
    state = Collector(client, node.keys.topic("actuation/state"), m.ArmStateMsg)
    z = {"options": names, "values": (0.3, -0.3) if n_options == 2 else (0.3, -0.1, -0.2)}

    def inputs() -> None:
        z_r.put(src_seq=0, **z)
        hands.put(detected=True, center=(0.5, 0.85), landmarks=((0.5, 0.85),))

    try:
        with _running(node, inputs, 0.02):
            wait_for(lambda: any(not s.safe_stop for s in state.messages[-3:]), 10.0, "arm up")
            arm.inject_fault("bus silent")
            wait_for(
                lambda: any(
                    s.safe_stop and "device fault" in s.safety_reason and s.fault == "bus silent"
                    for s in state.messages[-3:]
                ),
                5.0,
                "the device fault's safe stop",
            )
            arm.clear_fault()
            wait_for(lambda: not state.messages[-1].safe_stop, 10.0, "clear once healthy")
    finally:
        for other in (peer, camera):
            other.close()
        arm.disconnect()
