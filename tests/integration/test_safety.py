"""Safety over the fabric: an e-stop, stale inputs and lost liveliness stop a moving arm."""

import threading
import time

import pytest

from services.core import messages as m
from services.core.keys import Keys
from services.model.geometry import COLOURS

from .conftest import Collector, wait_for

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")
BOUND_NS = 250_000_000


class Feeder:
    """Stands in for vision and decision: fresh hand poses and a steady z_r toward red."""

    def __init__(self, client) -> None:
        self.hand = client.declare_publisher(KEYS.topic("vision/hand"))
        self.z_r = client.declare_publisher(KEYS.topic("decision/z_r"))
        self.tokens = [
            client.liveliness().declare_token(KEYS.alive(s))
            for s in ("decision", "vision", "experiment")  # the conductor too: a trial needs it
        ]
        self.running = threading.Event()
        self.running.set()
        self.quit = threading.Event()
        self.seq = 0
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        while not self.quit.is_set():
            if self.running.is_set():
                t = time.time_ns()
                self.seq += 1
                self.hand.put(
                    m.encode(
                        m.HandPose(
                            seq=self.seq,
                            t_ns=t,
                            detected=True,
                            center=(0.5, 0.85),
                            landmarks=((0.5, 0.85),),
                        )
                    )
                )
                self.z_r.put(m.encode(m.Opinions(seq=self.seq, t_ns=t, src_seq=self.seq,
                                                 **m.signed_fields(0.3))))
            time.sleep(0.01)

    def close(self) -> None:
        self.quit.set()
        self.thread.join()
        for token in self.tokens:
            token.undeclare()


def _start_moving(client, spawn):
    spawn("actuation")
    state = Collector(client, KEYS.topic("actuation/state"), m.ArmStateMsg)
    feeder = Feeder(client)
    trial = client.declare_publisher(KEYS.topic("experiment/trial"))
    wait_for(lambda: any(not s.safe_stop for s in state.messages[-3:]), 20, "actuation ready")
    trial.put(m.encode(m.TrialEvent(seq=0, t_ns=time.time_ns(), options=COLOURS, phase="setup",
                                    trial=1)))
    wait_for(lambda: bool(state.messages) and state.messages[-1].trial == 1, 10, "trial 1 set up")
    trial.put(m.encode(m.TrialEvent(seq=1, t_ns=time.time_ns(), options=COLOURS, phase="go",
                                    trial=1)))
    wait_for(lambda: bool(state.messages) and state.messages[-1].moving, 10, "the arm moving")
    return state, feeder


def _first_after(state: Collector, t_ns: int, pred):
    return next((s for s in state.messages if s.t_ns >= t_ns and pred(s)), None)


def test_estop_stops_the_arm_within_the_bound_and_latches(client, spawn):
    state, feeder = _start_moving(client, spawn)
    try:
        estop = client.declare_publisher(KEYS.topic("safety/estop"))
        release = client.declare_publisher(KEYS.topic("safety/release"))
        t_estop = time.time_ns()
        estop.put(m.encode(m.Estop(seq=0, t_ns=t_estop, engaged=True, reason="test", id="5-e1")))
        wait_for(
            lambda: _first_after(state, t_estop, lambda s: not s.moving) is not None,
            5,
            "the arm at rest after the e-stop",
        )
        flagged = _first_after(state, t_estop, lambda s: s.safe_stop)
        stopped = _first_after(state, t_estop, lambda s: not s.moving)
        assert flagged is not None and "e-stop" in flagged.safety_reason
        assert flagged.t_ns - t_estop <= BOUND_NS
        assert stopped.t_ns - t_estop <= BOUND_NS  # braking included
        time.sleep(0.3)  # a negative check: inputs stay fresh, yet the e-stop latches
        assert all(s.safe_stop and not s.moving for s in state.messages[-5:])
        t_rel = time.time_ns()
        estop.put(m.encode(m.Estop(seq=1, t_ns=t_rel, engaged=False, reason="wrong key", id="7-w")))
        # A release without an id, or issued before the engage (replayed), is refused too.
        release.put(m.encode(m.Estop(seq=2, t_ns=time.time_ns(), engaged=False, reason="no id")))
        release.put(m.encode(m.Estop(seq=3, t_ns=time.time_ns(), engaged=False, reason="old",
                                     id="4-r0")))
        time.sleep(0.3)  # a negative check: all refused, still stopped
        assert all(s.safe_stop and not s.moving and s.estop_id == "5-e1"
                   for s in state.messages[-5:])
        release.put(m.encode(m.Estop(seq=4, t_ns=time.time_ns(), engaged=False, reason="test",
                                     id="6-r1")))
        wait_for(
            lambda: _first_after(state, t_rel, lambda s: s.moving) is not None,
            5,
            "the arm moving again after the release",
        )
    finally:
        feeder.close()


def test_stale_input_and_lost_liveliness_stop_the_arm(client, spawn):
    state, feeder = _start_moving(client, spawn)
    try:
        feeder.running.clear()  # the camera and decision go silent
        t_quiet = time.time_ns()
        wait_for(
            lambda: _first_after(state, t_quiet, lambda s: s.safe_stop) is not None,
            5,
            "a safe stop on stale input",
        )
        flagged = _first_after(state, t_quiet, lambda s: s.safe_stop)
        assert "stale" in flagged.safety_reason
        assert flagged.t_ns - t_quiet <= BOUND_NS + 60_000_000  # bound + one tick + jitter
        feeder.running.set()
        wait_for(lambda: not state.messages[-1].safe_stop, 5, "recovery on fresh input")
        feeder.tokens[0].undeclare()  # decision's liveliness token goes away
        t_lost = time.time_ns()
        wait_for(
            lambda: _first_after(state, t_lost, lambda s: s.safe_stop) is not None,
            5,
            "a safe stop on lost liveliness",
        )
        assert (
            "decision not alive" in _first_after(state, t_lost, lambda s: s.safe_stop).safety_reason
        )
        feeder.tokens = feeder.tokens[1:]
    finally:
        feeder.close()


def test_future_stamps_cannot_hold_the_gate_open(client, spawn):
    # What would fool a gate that trusts stamps for good: a pose and a z_r stamped an hour ahead,
    # then silence; and a z_r stamped 2^63-1 (actuation frozen at 100% CPU). Freshness is judged
    # by arrival.
    state, feeder = _start_moving(client, spawn)
    try:
        feeder.running.clear()
        t = time.time_ns()
        hour = 3600 * 10**9
        forged_hand = m.HandPose(
            seq=10**6, t_ns=t + hour, detected=True, center=(0.5, 0.85), landmarks=((0.5, 0.85),)
        )
        feeder.hand.put(m.encode(forged_hand))
        feeder.z_r.put(m.encode(m.Opinions(seq=10**6, t_ns=t + hour, src_seq=1,
                                           **m.signed_fields(0.3))))
        feeder.z_r.put(m.encode(m.Opinions(seq=10**6 + 1, t_ns=2**63 - 1, src_seq=2,
                                           **m.signed_fields(0.3))))
        t_quiet = time.time_ns()
        wait_for(
            lambda: _first_after(state, t_quiet, lambda s: s.safe_stop) is not None,
            5,
            "a safe stop although the last inputs were stamped in the future",
        )
        flagged = _first_after(state, t_quiet, lambda s: s.safe_stop)
        assert flagged.t_ns - t_quiet <= BOUND_NS + 60_000_000
        assert "stale" in flagged.safety_reason
        # Still alive and ticking at its 50 Hz (the 2^63-1 stamp once stopped the state key).
        n = len(state.messages)
        time.sleep(1.0)  # a rate's window, not a wait for a condition
        assert len(state.messages) - n >= 30
        assert all(s.safe_stop and not s.moving for s in state.messages[-10:])
    finally:
        feeder.close()
