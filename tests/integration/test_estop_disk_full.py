"""An e-stop that cannot be saved is never acknowledged, and no restart lifts it.

The devices keep their latch on a real filesystem that fills up while the rig runs (a 64 kB
tmpfs, `small_disk`). The audit's fault: `nod estop` said "acknowledged by every device", and
after kill -9 of actuation and eyes the arm was free to move 1.3-2.4 s later.
"""

from __future__ import annotations

import time

import pytest

from services.core import messages as m
from services.core.keys import Keys

from .conftest import Collector, connect_when_listening, free_port, wait_for
from .test_estop_restarts import Procs, estop, free_to_move, rig_free_to_run, states_since

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")


def test_an_estop_on_a_full_disk_is_not_acknowledged_and_survives_kill9(tmp_path, small_disk):
    state = ("--state-dir", str(small_disk.path / "state"))
    with rig_free_to_run(tmp_path, *state) as (rig, arm, eyes):
        endpoint = rig.endpoint
        small_disk.fill()
        t_engaged = time.monotonic()
        engaged = estop(endpoint, "--reason", "disk full test")
        said = engaged.stdout + engaged.stderr
        assert engaged.returncode != 0, said
        for device in ("actuation", "eyes"):
            assert f"{device}: alive but did NOT acknowledge" in said, said
        assert "No space left on device" in said and "NOT by every device" in said, said
        # Stopped all the same, and saying why on the state keys.
        wait_for(lambda: any("e-stop latch not saved" in s.safety_reason
                             for s in states_since(arm, t_engaged)), 10, "the arm saying why")
        rig.kill9("actuation", "eyes")
        t_kill = time.monotonic()
        rig.restart("actuation", "eyes")
        # Where the latch cannot be kept a device does not start: it exits, one line, unmoved.
        for device in ("actuation", "eyes"):
            proc = rig.procs[device]
            wait_for(lambda p=proc: p.poll() is not None, 60, f"{device} refusing to start")
            assert proc.returncode != 0
            log = (tmp_path / f"{device}.log").read_text()
            assert "cannot keep the e-stop latch" in log and "Traceback" not in log, log
        for device, states in (("actuation", arm), ("eyes", eyes)):
            since = states_since(states, t_engaged)
            first = next(i for i, s in enumerate(since) if s.estop)  # the device heard it
            moving = free_to_move(since[first:])
            assert not moving, f"{device} reported free to move after the engage: {moving[:3]}"
        assert not states_since(arm, t_kill + 0.5)  # nothing drives the arm now


def test_an_unsaved_estop_is_saved_once_the_disk_frees_and_then_survives_kill9(
    tmp_path, small_disk
):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    state = ("--state-dir", str(small_disk.path / "state"))
    rig = Procs(endpoint, tmp_path)
    rig.start("router")
    client = None
    try:
        client = connect_when_listening(endpoint)
        rig.start("actuation", *state)
        arm = Collector(client, KEYS.topic("actuation/state"), m.ArmStateMsg)
        wait_for(lambda: arm.items and "starting" not in arm.items[-1][1].safety_reason
                 and "not known" not in arm.items[-1][1].safety_reason, 40, "the arm up")
        small_disk.fill()
        engaged = estop(endpoint, "--devices", "actuation", "--reason", "held")
        assert engaged.returncode != 0, engaged.stdout + engaged.stderr
        small_disk.free()  # the operator makes room: the device saves its latch by itself
        t_free = time.monotonic()
        wait_for(lambda: any(s.estop and "not saved" not in s.safety_reason
                             for s in states_since(arm, t_free)), 20, "the latch saved")
        rig.kill9("actuation")
        t_kill = time.monotonic()
        rig.restart("actuation")
        wait_for(lambda: len(states_since(arm, t_kill)) >= 25, 40, "the arm back")
        assert all(s.estop and s.safe_stop for s in states_since(arm, t_kill))
        released = estop(endpoint, "--devices", "actuation", "--release")
        assert released.returncode == 0, released.stdout + released.stderr
    finally:
        if client is not None:
            client.close()
        rig.stop()
