"""Unplugged ports recover: each driver, on a real pty that vanishes and comes back."""

from __future__ import annotations

import pytest
import serial

from services.actuation.arm_path import ArmPoses
from services.actuation.feetech_arm import FeetechArm, FeetechArmConfig
from services.core.serial_link import (
    LinkConfig,
    LinkLostError,
    LinkTimeoutError,
    SerialLink,
)
from services.eyes.arduino import ArduinoEyesConfig, ArduinoServoDriver
from services.eyes.maestro import MaestroConfig, MaestroServoDriver
from services.model.behaviour import ArmCommand
from services.model.gaze import GazeCommand
from services.model.geometry import TableLayout
from tests.emulators.arduino_emulator import ArduinoEyesEmulator
from tests.emulators.feetech_emulator import FeetechBusEmulator
from tests.emulators.links import LINK
from tests.emulators.maestro_emulator import MaestroEmulator
from tests.polling import eventually

# An unplugged port fails at once (EIO / ENOENT), whatever the reply timeout: keep that generous
# so a loaded machine cannot fail the healthy parts; reopen quickly.


# -- the link alone -----------------------------------------------------------------------------
class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.now += s


def test_backoff_grows_caps_and_resets():
    clock = FakeClock()
    available = {"ok": False}
    opened: list[float] = []

    class Port:
        def close(self) -> None: ...

    def factory(port, baud, timeout, write_timeout):
        opened.append(clock.now)
        if not available["ok"]:
            raise serial.SerialException(f"[Errno 2] could not open port {port}")
        return Port()

    cfg = LinkConfig(backoff_initial_s=0.5, backoff_factor=2.0, backoff_max_s=2.0)
    link = SerialLink(
        "/dev/ttyFAKE", 9600, cfg, serial_factory=factory, clock=clock, sleep=clock.sleep
    )
    with pytest.raises(LinkLostError, match="cannot open serial port /dev/ttyFAKE"):
        link.open()
    assert "reopening /dev/ttyFAKE in 0.5 s (attempt 1)" in (link.fault or "")
    assert not link.ensure_open()  # too early: no attempt
    assert len(opened) == 1
    assert not link.wait_open(3.6)  # attempts at +0.5, +1.5 (1 s), +3.5 (2 s, capped)
    assert [round(t - 100.0, 3) for t in opened] == [0.0, 0.5, 1.5, 3.5]
    available["ok"] = True
    assert link.wait_open(5.0) and link.is_open and link.fault is None
    assert link.opens == 1


def test_repeated_timeouts_reopen_the_port():
    with MaestroEmulator() as emu:
        link = SerialLink(
            emu.port, 9600, LinkConfig(timeout_s=0.05, max_timeouts=2, backoff_initial_s=0.01)
        )
        link.open()
        emu.silent = True
        with pytest.raises(LinkTimeoutError):
            link.transact(b"\xa1", 2)
        assert link.is_open
        with pytest.raises(LinkTimeoutError, match="2 times in a row"):
            link.transact(b"\xa1", 2)
        assert not link.is_open  # closed, reopen scheduled
        emu.silent = False
        assert eventually(link.ensure_open) and link.opens == 2
        assert link.transact(b"\xa1", 2) == b"\x00\x00"
        link.close()


# -- the drivers ----------------------------------------------------------------------------------
def test_maestro_recovers_after_unplug():
    with MaestroEmulator() as emu:
        drv = MaestroServoDriver(emu.port, MaestroConfig(speed=20, link=LINK))
        drv.connect()
        drv.look(GazeCommand(0.3, -0.1))
        assert drv.settle(2.0)  # the driver's I/O runs on its own thread
        emu.unplug()
        applied = drv.look(GazeCommand(-0.6, 0.2))  # must not raise
        assert drv.settle(2.0)  # the driver's I/O runs on its own thread
        assert drv.fault is not None and drv.is_connected
        assert drv.poll(wait_s=2.0) is not None  # still gone
        emu.replug()  # a power-cycled Maestro: targets off, speeds reset
        assert eventually(lambda: drv.poll(wait_s=2.0) is None)
        assert emu.channels[0].speed == 20  # initialised again
        assert emu.targets_us() == tuple(round(p * 4) / 4 for p in applied.pulses_us)
        drv.disconnect()


def test_arduino_recovers_after_unplug():
    with ArduinoEyesEmulator() as emu:
        drv = ArduinoServoDriver(emu.port, ArduinoEyesConfig(boot_wait_s=1.0, link=LINK))
        drv.connect()
        emu.unplug()
        applied = drv.look(GazeCommand(0.62, -0.62))
        assert drv.settle(2.0)  # the driver's I/O runs on its own thread
        assert drv.fault is not None
        emu.replug()
        emu.boot_frames = 1  # the reset on open: the bootloader eats the first ping
        assert eventually(lambda: drv.poll(wait_s=2.0) is None)
        assert emu.pulses == [round(p) for p in applied.pulses_us]
        drv.disconnect()


def test_feetech_arm_freezes_then_holds_after_unplug():
    ids = (1, 2)
    poses = ArmPoses((2048, 2048), (2448, 2148), (2448, 2348), (1648, 2148), (1648, 2348))
    cfg = FeetechArmConfig(ids=ids, move_time_s=2.0, poll_interval_s=0.05, poses=poses, link=LINK)
    with FeetechBusEmulator({1: 2048, 2: 2048}) as emu:
        arm = FeetechArm(emu.port, cfg, TableLayout())
        arm.connect()
        arm.state(0.0)
        arm.send(ArmCommand.move(+1))
        arm.state(1.0)  # halfway to red
        # SYNC_WRITE has no reply: let the servos get it before the cable is pulled (bytes in
        # flight are lost with the cable, and the arm would rightly relocate elsewhere)
        assert emu.wait_until(lambda: emu.goals() == {1: 2248, 2: 2098})
        emu.unplug()
        t = 1.0
        st = arm.state(t + 0.02)
        assert st.fault is not None and not st.moving
        assert arm.send(ArmCommand.move(+1)).action == "stop"  # refused while faulted
        frozen = arm.path
        emu.replug()

        def healthy() -> bool:
            nonlocal t
            t += 0.05
            return arm.state(t).fault is None

        assert eventually(healthy)
        assert arm.path == pytest.approx(frozen, abs=0.01)  # relocated where it stood
        assert emu.goals() == emu.positions()  # holding, torque on
        assert all(s.get("torque_enable") == 1 for s in emu.servos.values())
        arm.send(ArmCommand.move(+1))
        arm.state(t + 5.0)
        assert emu.wait_until(lambda: emu.goals() == {1: 2448, 2: 2148})
        arm.disconnect()
