"""A device fault is a safety event: a device's bus goes silent, then is unplugged, mid-trial.

`nod run --sim` drives a real device driver (in its own service process) over a real pty: the
arm's Feetech bus, or the eyes' Maestro controller, played by an emulator. Each fault must
safe-stop that device within 300 ms, interrupt the trial (stored with the fault in
`interruptions` and `safety_events`) and have it repeated, never scored; the session completes
once the device is healthy again. The arm's faults are tested on the paper's table and on one of
three boxes (its arm file a press pose per option), through the same driver.
"""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from services.actuation.calibrate import config_toml
from services.actuation.feetech_arm import FeetechArmConfig
from services.core import messages as m
from services.core.keys import Keys
from services.store import Store
from tests.emulators.feetech_emulator import IDS, POSES_BY_N
from tests.emulators.links import RIG
from tests.emulators.own_process import DeviceProcess
from tests.processes import stop_all

from .conftest import (
    RELAXED,
    ROOT,
    SHORT,
    SHORT_THREE,
    Collector,
    connect_when_listening,
    free_port,
    wait_for,
)

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")
FAULT_BOUND_S = 0.3
FAULT_S = 0.8  # how long the device stays faulty: well past the bound, then it heals itself


def _go_of(events: Collector, trial: int, after: int = 0) -> bool:
    return any(e.phase == "go" and e.trial == trial for e in events.messages[after:])


def _fault_stop_after(states: Collector, t: float) -> float | None:
    return next(
        (at for at, s in states.items
         if at >= t and s.safe_stop and "device fault" in s.safety_reason),
        None,
    )


@pytest.mark.parametrize(("device", "n_options"), [("actuation", 2), ("actuation", 3),
                                                   ("eyes", 2)])
def test_a_silent_and_an_unplugged_bus_interrupt_their_trials(tmp_path, device, n_options):
    params = tmp_path / "short.toml"
    # the fault's own detection is what is timed; three trials of the table's options
    params.write_text(RELAXED if n_options == 2 else SHORT_THREE + RELAXED.removeprefix(SHORT))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    db = tmp_path / "s.sqlite"
    if device == "actuation":
        arm_file = tmp_path / "arm.toml"
        poses = POSES_BY_N[n_options]
        arm_file.write_text(config_toml(FeetechArmConfig(ids=IDS, poses=poses, link=RIG)))
        emulator = DeviceProcess("feetech", tmp_path)
        state_cls = m.ArmStateMsg
        flags = ["--arm-driver", "feetech", "--arm-port", "{port}", "--arm-config", str(arm_file)]
    else:
        emulator = DeviceProcess("maestro", tmp_path)
        state_cls = m.EyesStateMsg
        flags = ["--eyes-driver", "maestro", "--eyes-port", "{port}"]
    # The device in a process of its own: its replies are timed against the driver's 50 ms.
    with emulator as bus:
        hardware = [f.format(port=bus.port) for f in flags]
        run = subprocess.Popen(
            [sys.executable, "-m", "services.cli", "run", "--sim", "--speed", "2",
             "--params", str(params), "--db", str(db), "--listen", endpoint,
             "--logs", str(tmp_path / "logs"), *hardware],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )
        client = None
        try:
            client = connect_when_listening(endpoint)
            events = Collector(client, KEYS.topic("experiment/trial"), m.TrialEvent)
            arm = Collector(client, KEYS.topic(f"{device}/state"), state_cls)
            delays = {}
            for trial, fault in ((2, "silent"), (3, "unplugged")):
                wait_for(lambda t=trial: _go_of(events, t), 120, f"trial {trial} under way")
                if device == "actuation":  # the fault comes with the arm on its way
                    wait_for(lambda: any(s.moving for s in arm.messages[-3:]), 10, "the arm moving")
                seen = len(events.messages)
                t_fault = time.monotonic()
                bus.fault_for(fault, FAULT_S)
                wait_for(lambda t=t_fault: _fault_stop_after(arm, t) is not None, 5,
                         f"a safe stop for the {fault} bus")
                delays[fault] = _fault_stop_after(arm, t_fault) - t_fault
                wait_for(
                    lambda t=trial, n=seen: any(
                        e.phase == "interrupted" and e.trial == t for e in events.messages[n:]
                    ),
                    10,
                    f"trial {trial} interrupted by the {fault} bus",
                )
                wait_for(lambda t=trial, n=seen: _go_of(events, t, n), 60,
                         f"trial {trial} repeated once the bus is back")
            out, _ = run.communicate(timeout=180)
        finally:
            if client is not None:
                client.close()
            stop_all([run])
    assert run.returncode == 0, out[-3000:]
    print(f"\n{device} safe stop after the bus fault: "
          f"{ {k: round(v * 1e3) for k, v in delays.items()} } ms")
    assert all(d <= FAULT_BOUND_S for d in delays.values()), delays
    store = Store(db)
    try:
        (session,) = [s["session"] for s in store.sessions()]
        trials = {t.trial: t for _, t in store.trials(session)}
        interruptions = store.interruptions(session)
        faults = [e for e in store.safety_events(session)
                  if e.device == device and "device fault" in e.reason]
    finally:
        store.close()
    assert sorted(trials) == [1, 2, 3]
    for trial in (2, 3):  # broken by the fault, repeated, and the repeat scored like any trial
        # (a loaded machine may break an attempt more, by a late input: never fewer)
        reasons = [i.reason for i in interruptions if i.trial == trial]
        assert any(why.startswith(f"{device}: ") and "device fault" in why for why in reasons), (
            trial, reasons)
        assert trials[trial].attempts == len(reasons) + 1, (trials[trial], reasons)
        assert not trials[trial].interrupted and trials[trial].outcome is not None
    assert {e.trial for e in faults} >= {2, 3}, faults
