"""The Maestro driver, byte-exact, against a Maestro emulator on a real pty."""

from __future__ import annotations

import math
import time
from pathlib import Path

import pytest

from services.core.serial_link import LinkConfig
from services.eyes.maestro import (
    MaestroConfig,
    MaestroServoDriver,
    describe_errors,
    quarter_us,
    set_target,
)
from services.eyes.servos import ServoNotConnectedError
from services.model.gaze import GAZE_LEVELS, GazeCommand, attention_gesture
from services.model.servos import EyesCalibration, ServoCalibration, ServoTargets, servo_targets
from tests.emulators.links import FAST, LINK
from tests.emulators.maestro_emulator import ERR_PROTOCOL, MaestroEmulator
from tests.polling import eventually


@pytest.fixture
def maestro():
    with MaestroEmulator() as emu:
        yield emu


def driver_for(emu: MaestroEmulator, link: LinkConfig = LINK, **kw) -> MaestroServoDriver:
    return MaestroServoDriver(emu.port, MaestroConfig(link=link, **kw))


def test_codec_matches_the_users_guide_example():
    # User's guide: "0x84, 0x00, 0x70, 0x2E" sets channel 0 to 1500 µs (6000 quarter-µs).
    assert set_target(0, quarter_us(1500.0)) == bytes((0x84, 0x00, 0x70, 0x2E))
    assert set_target(5, 0) == bytes((0x84, 0x05, 0x00, 0x00))
    with pytest.raises(ValueError, match="channel"):
        set_target(24, 6000)
    with pytest.raises(ValueError, match="value"):
        set_target(0, 0x4000)
    assert "serial protocol error" in describe_errors(0x0010)


def test_config_is_validated():
    with pytest.raises(ValueError, match="distinct"):
        MaestroConfig(channels=(0, 0, 1, 2))
    with pytest.raises(ValueError, match="acceleration"):
        MaestroConfig(acceleration=300)


def test_connect_sets_speed_and_acceleration_then_checks_errors(maestro):
    drv = driver_for(maestro, speed=40, acceleration=3)
    drv.connect()
    try:
        sent = maestro.take_received()
        expected = b"".join(
            bytes((0x87, ch, 40, 0)) + bytes((0x89, ch, 3, 0)) for ch in (0, 1, 2, 3)
        )
        assert sent == expected + bytes((0xA1,))
        assert [c.speed for c in maestro.channels[:4]] == [40] * 4
        assert drv.fault is None
    finally:
        drv.disconnect()


def test_a_gaze_command_becomes_the_right_bytes(maestro):
    calib = EyesCalibration(
        left_pan=ServoCalibration(trim_deg=2.0),
        right_pan=ServoCalibration(direction=-1),
    )
    drv = MaestroServoDriver(maestro.port, MaestroConfig(channels=(3, 2, 1, 0), link=LINK), calib)
    with drv:
        maestro.take_received()
        yaw = GAZE_LEVELS["low"].yaw  # +0.53 rad toward red
        pitch = GAZE_LEVELS["low"].pitch
        applied = drv.look(GazeCommand(yaw, pitch))
        assert drv.settle(2.0)  # the driver's I/O runs on its own thread
        # left pan: 90 + 30.37 + 2 deg; right pan mirrored: 90 - 30.37 deg; tilts: 90 - 30.37.
        deg = math.degrees(yaw)

        def qus(angle: float) -> int:
            return round((500 + angle / 180 * 2000) * 4)

        tilt = qus(90 + math.degrees(pitch))
        expected_qus = [qus(90 + deg + 2), tilt, qus(90 - deg), tilt]
        pairs = zip((3, 2, 1, 0), expected_qus, strict=True)
        expected = b"".join(bytes((0x84, ch, q & 0x7F, q >> 7)) for ch, q in pairs)
        assert maestro.take_received() == expected + bytes((0xA1,))
        assert applied == servo_targets(GazeCommand(yaw, pitch), calib)
        # channel 3 drives the left pan, channel 0 the right tilt
        assert maestro.channels[3].target == expected_qus[0]
        assert maestro.channels[0].target == expected_qus[3]
        assert drv.read_positions_us() == tuple(q / 4 for q in expected_qus)
        assert drv.fault is None


def test_out_of_range_is_clamped_and_reported_never_sent_raw(maestro):
    calib = EyesCalibration(left_pan=ServoCalibration(min_deg=30.0, max_deg=150.0))
    with MaestroServoDriver(maestro.port, MaestroConfig(link=LINK), calib) as drv:
        maestro.take_received()
        applied = drv.look(GazeCommand(yaw=3.0, pitch=0.0))  # 172° on the left pan
        assert drv.settle(2.0)  # the driver's I/O runs on its own thread
        assert "left_pan" in applied.clamped
        assert maestro.channels[0].target == quarter_us(500 + 150 / 180 * 2000)
        # a hand-built target outside the limits is re-clamped by the driver too
        raw = ServoTargets((0.0, 90.0, 90.0, 90.0), (500.0, 1500.0, 1500.0, 1500.0))
        assert drv.send(raw).angles_deg[0] == 30.0
        assert drv.settle(2.0)  # the driver's I/O runs on its own thread
        assert maestro.channels[0].target == quarter_us(500 + 30 / 180 * 2000)


def test_attention_gesture_is_a_timed_sequence_of_targets(maestro):
    with driver_for(maestro) as drv:
        seq = attention_gesture(start_t=0.0)
        for _, cmd in seq:
            drv.look(cmd)
            assert drv.settle(2.0)  # the driver's I/O runs on its own thread
        settle = seq[-1][1]
        assert maestro.targets_us() == tuple(
            quarter_us(p) / 4 for p in servo_targets(settle, drv.calibration).pulses_us
        )
        targets = [p for p in maestro.commands if p[0] == 0x84 and p[1] == 0]
        assert len(targets) == len(seq)


def test_protocol_errors_reported_and_targets_resent(maestro):
    with driver_for(maestro) as drv:
        drv.look(GazeCommand(0.2, 0.1))
        assert drv.settle(2.0)  # the driver's I/O runs on its own thread
        assert drv.fault is None
        maestro.inject_errors(ERR_PROTOCOL)  # e.g. line noise on a TTL link
        assert "serial protocol error" in (drv.poll(wait_s=2.0) or "")
        maestro.take_received()
        assert drv.poll(wait_s=2.0) is None  # errors were cleared by reading them...
        resent = maestro.take_received()  # ...and the latched targets written again
        assert resent[:4] == set_target(0, quarter_us(drv.latched.pulses_us[0]))


def test_silence_is_detected_within_the_timeout(maestro):
    with driver_for(maestro, link=FAST) as drv:
        maestro.silent = True
        t0 = time.monotonic()
        applied = drv.look(GazeCommand(0.3, 0.0))  # does not raise
        assert drv.settle(2.0)  # the driver's I/O runs on its own thread
        assert time.monotonic() - t0 < 1.0  # bounded by the 50 ms timeout, not a hang
        assert applied.angles_deg[0] == pytest.approx(90 + math.degrees(0.3))
        assert "no Get Errors reply" in (drv.fault or "")
        maestro.silent = False
        assert eventually(lambda: drv.poll(wait_s=2.0) is None)
        assert maestro.targets_us()[0] == quarter_us(applied.pulses_us[0]) / 4


def test_connect_fails_clearly_when_nothing_answers(maestro, tmp_path):
    maestro.silent = True
    with pytest.raises(ConnectionError, match="USB Dual Port"):
        driver_for(maestro, link=FAST).connect()
    with pytest.raises(ConnectionError, match="cannot open"):
        MaestroServoDriver(str(tmp_path / "nope"), MaestroConfig(link=FAST)).connect()
    with pytest.raises(ServoNotConnectedError):
        driver_for(maestro).neutral()


def test_factory_builds_each_eyes_driver_from_the_example_file():
    from services.eyes.arduino import ArduinoServoDriver
    from services.eyes.drivers import load_eyes_config, make_eyes_driver
    from services.eyes.servos import SimServoDriver

    example = Path(__file__).resolve().parents[2] / "deploy/hardware/eyes.example.toml"
    hw = load_eyes_config(example)
    assert hw.calibration is not None and hw.calibration.right_tilt.direction == -1
    drv = make_eyes_driver("maestro", "/dev/ttyACM0", example)
    assert isinstance(drv, MaestroServoDriver) and drv.calibration == hw.calibration
    assert drv.config.channels == (0, 1, 2, 3) and not drv.is_connected
    assert isinstance(make_eyes_driver("arduino", "/dev/ttyUSB0", example), ArduinoServoDriver)
    own = EyesCalibration(left_pan=ServoCalibration(trim_deg=4.0))
    sim = make_eyes_driver("sim", None, None, calibration=own)
    assert isinstance(sim, SimServoDriver) and sim.calibration == own
    with pytest.raises(ValueError, match="--port"):
        make_eyes_driver("maestro", None, None)
    with pytest.raises(ValueError, match="unknown eyes driver"):
        make_eyes_driver("dynamixel", "/dev/x", None)
