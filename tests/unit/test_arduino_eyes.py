"""The Arduino eyes driver, byte-exact, against the sketch's protocol emulated on a real pty."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import pytest

from services.core.serial_link import LinkConfig
from services.eyes.arduino import (
    ArduinoEyesConfig,
    ArduinoServoDriver,
    crc8,
    encode_frame,
)
from services.model.gaze import GAZE_LEVELS, GazeCommand
from services.model.servos import EyesCalibration, ServoCalibration, servo_targets
from tests.emulators.arduino_emulator import ArduinoEyesEmulator, crc8_smbus
from tests.emulators.links import FAST, LINK
from tests.polling import eventually


@pytest.fixture
def board():
    with ArduinoEyesEmulator() as emu:
        yield emu


def driver_for(
    emu: ArduinoEyesEmulator, calib: EyesCalibration | None = None, link: LinkConfig = LINK
) -> ArduinoServoDriver:
    return ArduinoServoDriver(emu.port, ArduinoEyesConfig(boot_wait_s=2.0, link=link), calib)


def test_crc8_is_crc8_smbus():
    assert crc8(b"123456789") == 0xF4  # the catalogue check value of CRC-8/SMBUS
    assert crc8(b"123456789") == crc8_smbus(b"123456789")  # the emulator's own implementation
    assert encode_frame(0x01) == bytes((0xA5, 0x01, 0x00, crc8(b"\x01\x00")))
    with pytest.raises(ValueError):
        encode_frame(0x02, bytes(17))


def test_a_gaze_command_becomes_the_right_frame(board):
    calib = EyesCalibration(right_tilt=ServoCalibration(direction=-1, trim_deg=-3.0))
    with driver_for(board, calib) as drv:
        board.take_received()
        level = GAZE_LEVELS["extreme"]
        applied = drv.look(GazeCommand(level.yaw, level.pitch))
        assert drv.settle(2.0)  # the driver's I/O runs on its own thread
        assert applied == servo_targets(GazeCommand(level.yaw, level.pitch), calib)
        pulses = [round(p) for p in applied.pulses_us]
        payload = struct.pack("<4H", *pulses)
        body = bytes((0x02, 8)) + payload
        assert board.take_received() == bytes((0xA5,)) + body + bytes((crc8(body),))
        assert board.pulses == pulses
        # left pan: 90° + 62.45° → 500 + 152.45/180·2000 µs
        assert pulses[0] == round(500 + (90 + math.degrees(1.09)) / 180 * 2000)
        assert drv.read_pulses_us() == tuple(pulses)
        assert drv.fault is None


def test_connect_waits_for_the_bootloader(board):
    board.boot_frames = 2  # the first two pings vanish into the bootloader
    with driver_for(board, link=FAST) as drv:
        pings = [f for f in board.frames if f[0] == 0x01]
        assert len(pings) >= 1 and drv.fault is None
        assert board.take_received().count(encode_frame(0x01)) == 2 + len(pings)


def test_corrupt_reply_is_detected_and_the_targets_resent(board):
    with driver_for(board) as drv:
        board.corrupt_replies = 1
        applied = drv.look(GazeCommand(0.4, -0.2))
        assert drv.settle(2.0)  # the driver's I/O runs on its own thread
        assert "checksum" in (drv.fault or "")
        assert drv.poll(wait_s=2.0) is None
        assert board.pulses == [round(p) for p in applied.pulses_us]


def test_silence_is_detected_and_recovered(board):
    with driver_for(board, link=FAST) as drv:
        board.silent = True
        drv.look(GazeCommand(-0.47, 0.31))
        assert drv.settle(2.0)  # the driver's I/O runs on its own thread
        assert "no reply" in (drv.fault or "")
        assert "no reply" in (drv.poll(wait_s=2.0) or "")
        board.silent = False
        assert eventually(lambda: drv.poll(wait_s=2.0) is None)
        assert board.pulses == [round(p) for p in drv.latched.pulses_us]


def test_a_nak_is_reported(board):
    with driver_for(board) as drv:
        reply = drv.request(0x03)
        assert len(reply) == 8
        with pytest.raises(ConnectionError, match="unknown command"):
            drv.request(0x42)


def test_firmware_clamp_is_echoed_not_hidden(board):
    calib = EyesCalibration(
        left_pan=ServoCalibration(min_pulse_us=400.0, max_pulse_us=2600.0),
    )
    with driver_for(board, calib) as drv:
        applied = drv.look(GazeCommand(yaw=-2.0))  # 0° → 400 µs: below the sketch's 500 µs
        assert drv.settle(2.0)  # the driver's I/O runs on its own thread
        assert applied.pulses_us[0] == 400.0
        assert drv.firmware_pulses is not None and drv.firmware_pulses[0] == 500
        assert drv.fault is None


def test_connect_fails_clearly_when_the_sketch_is_missing(board):
    board.silent = True
    drv = ArduinoServoDriver(board.port, ArduinoEyesConfig(boot_wait_s=0.1, link=FAST))
    with pytest.raises(ConnectionError, match="eyes.ino"):
        drv.connect()
    assert not drv.is_connected


def test_protocol_doc_and_sketch_agree_with_the_driver():
    from services.eyes.arduino import encode_pulses

    root = Path(__file__).resolve().parents[2] / "firmware/eyes"
    doc = (root / "PROTOCOL.md").read_text()
    frame = encode_frame(0x02, encode_pulses((1500.0,) * 4))
    assert frame.hex(" ").upper() in doc  # the worked example is byte-exact
    sketch = (root / "eyes.ino").read_text()
    assert f"BAUD = {ArduinoEyesConfig().baudrate};" in sketch
    for const in ("SYNC = 0xA5", "CMD_SET_PULSES = 0x02", "NAK = 0x7F", "MIN_PULSE_US = 500"):
        assert const in sketch
