"""The e-stop is never behind data: under a flood of valid messages on the devices' input keys,
`nod estop` with its default timeout is acknowledged by both devices.

The audit's fault: with z_r flooded, `nod estop` exited 1 ("actuation did NOT acknowledge") and
the e-stopped state came 3.46 s later; the e-stop was decoded on the same path as the data,
behind it. `benchmarks/estop_flood.py` measures the acknowledgement's distribution.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from services.core import messages as m
from services.core.keys import Keys
from tests.processes import run_nod, stop_all

from .conftest import ROOT, Collector, wait_for

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")
RUNS = 5


@pytest.mark.parametrize("keys", ["z_r", "z_r,hand,gaze"])
def test_estop_is_acknowledged_within_its_default_timeout_under_a_flood(
    router, endpoint, client, spawn, keys
):
    arm = Collector(client, KEYS.topic("actuation/state"), m.ArmStateMsg)
    eyes = Collector(client, KEYS.topic("eyes/state"), m.EyesStateMsg)
    spawn("actuation")
    spawn("eyes")
    wait_for(lambda: len(arm.items) > 25 and len(eyes.items) > 25, 30, "devices up")
    flood = subprocess.Popen(
        [sys.executable, str(ROOT + "/benchmarks/flood.py"), "--connect", endpoint, "--keys",
         keys, "--seconds", "300"], stdout=subprocess.PIPE, text=True,
    )
    try:
        received = sum(1 for _ in arm.items)
        # The flood reaches the devices: their state keys go on, and the router is saturated.
        wait_for(lambda: flood.poll() is None and len(arm.items) > received + 50, 30,
                 "the flood under way")
        for i in range(RUNS):
            engaged = run_nod("estop", "--connect", endpoint, "--reason", f"flood {i}",
                              timeout=60)
            assert engaged.returncode == 0, f"run {i}: {engaged.stdout}{engaged.stderr}"
            released = run_nod("estop", "--connect", endpoint, "--release", timeout=60)
            assert released.returncode == 0, f"run {i}: {released.stdout}{released.stderr}"
        assert flood.poll() is None  # still flooding at the end
    finally:
        stop_all([flood])
    sent = flood.communicate(timeout=30)[0]
    print(f"\nflood ({keys}): {sent.strip()}")
