"""The e-stop wiring's order of work: stop, save, then acknowledge — and nothing unsaved is acked.

`watch_safety_inputs` runs on a node; here the node is a stand-in that records the handlers the
wiring declares (the fabric's part is tested by the integration tests), and the latch file is a
real file, or one whose saving fails as a full disk's does.
"""

from __future__ import annotations

import errno
import threading
from pathlib import Path

from services.core import messages as m
from services.model.latch import Latch
from services.model.safety import SafetyParams, Watchdog
from services.safety.latch_file import LatchFile
from services.safety.wiring import watch_safety_inputs


class StandInNode:
    """What the wiring asks of a node: a lock, a clock, and places to declare its handlers."""

    service = "actuation"

    def __init__(self) -> None:
        self.lock = threading.RLock()
        self.handlers: dict[str, object] = {}
        self.ticks: list = []
        self.clock = type("Clock", (), {"now_ns": staticmethod(lambda: 1)})()

    def subscribe_urgent(self, topic, handler):
        self.handlers[topic] = handler

    def every(self, period_s, fn):
        self.ticks.append(fn)

    def answer(self, topic, reply):
        self.handlers[topic] = reply

    def ask(self, topic, timeout_s):
        return []

    def watch_liveliness(self, service, on_change):
        pass


class RecordingLatchFile(LatchFile):
    """A real latch file that notes, at each save, whether the device had already stopped."""

    def __init__(self, folder: Path, watchdog_view, full: bool = False) -> None:
        super().__init__(folder, "rig1", "actuation")
        self.view = watchdog_view
        self.full = full
        self.saves: list[tuple[bool, bool]] = []  # (latch engaged, device stopped) at each save

    def save(self, latch: Latch) -> None:
        self.saves.append((latch.engaged, self.view()))
        if self.full:
            raise OSError(errno.ENOSPC, "No space left on device")
        super().save(latch)


def wired(tmp_path: Path, full: bool = False):
    node = StandInNode()
    watchdog = Watchdog(SafetyParams(require_alive=("decision",)), ("z_r",))
    stopped = {"now": False, "acks": []}

    def act_now(now_ns: int) -> None:  # what the device does: obey the gate, show the ack
        stopped["now"] = watchdog.check(now_ns).safe_stop
        stopped["acks"].append(watchdog.estop_id)

    latch_file = RecordingLatchFile(tmp_path, lambda: stopped["now"], full=full)
    watch_safety_inputs(node, watchdog, act_now, latch_file)
    watchdog.set_alive("decision", True)
    watchdog.feed("z_r", 1)
    return node, watchdog, latch_file, stopped


def estop(engaged: bool, cid: str) -> m.Estop:
    return m.Estop(seq=0, t_ns=1, engaged=engaged, reason="test", source="op@ctl", id=cid)


def test_an_engage_stops_the_device_before_its_latch_is_saved(tmp_path):
    node, watchdog, latch_file, stopped = wired(tmp_path)
    node.handlers["safety/estop"](estop(True, "10-e"))
    # The save saw the device already stopped (a slow fsync must not delay the stop)...
    assert latch_file.saves == [(True, True)]
    # ...and the acknowledgement came only after it: first the old id, then the new one.
    assert stopped["acks"] == ["", "10-e"] and LatchFile(tmp_path, "rig1", "actuation").load()


def test_a_release_is_saved_before_the_device_may_move(tmp_path):
    node, watchdog, latch_file, stopped = wired(tmp_path)
    node.handlers["safety/estop"](estop(True, "10-e"))
    node.handlers["safety/release"](estop(False, "11-r"))
    assert latch_file.saves[-1] == (False, True)  # saved while the device was still stopped
    assert not stopped["now"] and stopped["acks"][-1] == "11-r"
    assert not LatchFile(tmp_path, "rig1", "actuation").load().engaged


def test_on_a_full_disk_an_engage_is_obeyed_never_acknowledged_and_retried(tmp_path):
    node, watchdog, latch_file, stopped = wired(tmp_path, full=True)
    node.handlers["safety/estop"](estop(True, "10-e"))
    assert stopped["now"] and "10-e" not in stopped["acks"]
    assert "No space left on device" in watchdog.check(1).reason
    node.ticks[0](1)  # the retry, still full
    assert watchdog.estop_id != "10-e"
    latch_file.full = False  # room again: the next retry saves it and acknowledges
    node.ticks[0](1)
    assert watchdog.estop_id == "10-e" and watchdog.estopped
    assert LatchFile(tmp_path, "rig1", "actuation").load().engaged


def test_on_a_full_disk_a_release_is_not_obeyed(tmp_path):
    node, watchdog, latch_file, stopped = wired(tmp_path)
    node.handlers["safety/estop"](estop(True, "10-e"))
    latch_file.full = True
    node.handlers["safety/release"](estop(False, "11-r"))
    assert watchdog.estopped and stopped["now"] and stopped["acks"][-1] == "10-e"
    assert "release was not obeyed" in watchdog.check(1).reason
    latch_file.full = False
    node.handlers["safety/release"](estop(False, "11-r"))  # nod estop repeats it
    assert not watchdog.estopped and watchdog.estop_id == "11-r"
