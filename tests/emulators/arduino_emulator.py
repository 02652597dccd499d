"""The eyes sketch (firmware/eyes/eyes.ino) as a pty device: same parser, same replies.

A model of the sketch's `loop()`, written from firmware/eyes/PROTOCOL.md (not from the driver):
frames `0xA5 cmd len payload crc8`, PING / SET_PULSES / GET_PULSES, NAK codes, pulses clamped to
[MIN_PULSE_US, MAX_PULSE_US], neutral (1500 µs) after reset. Not modelled: the sketch's 50 ms
torn-frame timeout (the driver always sends whole frames).

Faults to inject: `silent` (no replies), `corrupt_replies` (the next n replies carry a wrong
CRC), `boot_frames` (the next n frames are swallowed, as by the bootloader after a reset).
"""

from __future__ import annotations

import struct
from pathlib import Path

from tests.emulators.pty_device import PtyDevice

SYNC = 0xA5
MAX_PAYLOAD = 16
MIN_PULSE_US = 500
MAX_PULSE_US = 2500
NEUTRAL_US = 1500
NAK = 0x7F
NAK_BAD_CRC, NAK_UNKNOWN, NAK_BAD_LENGTH = 1, 2, 3


def crc8_smbus(data: bytes) -> int:
    """Bitwise CRC-8, polynomial x^8 + x^2 + x + 1 (0x07), init 0 — as in the sketch."""
    crc = 0
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc << 1) ^ 0x07 if crc & 0x80 else crc << 1
            crc &= 0xFF
    return crc


class ArduinoEyesEmulator(PtyDevice):
    """The sketch with four servos."""

    def __init__(self, link_dir: Path | None = None) -> None:
        super().__init__(link_dir, "ttyUSB-eyes")
        self.pulses = [NEUTRAL_US] * 4
        self.frames: list[tuple[int, bytes]] = []  # every valid frame received (cmd, payload)
        self.corrupt_replies = 0
        self.boot_frames = 0
        self._buf = bytearray()

    def on_replug(self) -> None:
        """A reset: servos back to neutral, parser cleared."""
        self.pulses = [NEUTRAL_US] * 4
        self._buf.clear()

    def feed(self, data: bytes) -> None:
        """Parse frames; resynchronise on the next 0xA5 after garbage."""
        self._buf.extend(data)
        while self._buf:
            if self._buf[0] != SYNC:
                del self._buf[0]
                continue
            if len(self._buf) < 3:
                return
            length = self._buf[2]
            if length > MAX_PAYLOAD:
                del self._buf[0]
                self._reply(NAK, bytes((NAK_BAD_LENGTH,)))
                continue
            if len(self._buf) < 4 + length:
                return
            frame = bytes(self._buf[: 4 + length])
            del self._buf[: 4 + length]
            self._handle(frame)

    def _handle(self, frame: bytes) -> None:
        if self.boot_frames > 0:
            self.boot_frames -= 1
            return
        cmd, length, payload, crc = frame[1], frame[2], frame[3:-1], frame[-1]
        if crc8_smbus(frame[1:-1]) != crc:
            self._reply(NAK, bytes((NAK_BAD_CRC,)))
            return
        self.frames.append((cmd, payload))
        if cmd == 0x01:  # PING
            self._reply(0x81, bytes((1, 4)))
        elif cmd == 0x02:  # SET_PULSES
            if length != 8:
                self._reply(NAK, bytes((NAK_BAD_LENGTH,)))
                return
            values = struct.unpack("<4H", payload)
            self.pulses = [min(max(v, MIN_PULSE_US), MAX_PULSE_US) for v in values]
            self._reply(0x82, struct.pack("<4H", *self.pulses))
        elif cmd == 0x03:  # GET_PULSES
            self._reply(0x83, struct.pack("<4H", *self.pulses))
        else:
            self._reply(NAK, bytes((NAK_UNKNOWN,)))

    def _reply(self, cmd: int, payload: bytes) -> None:
        body = bytes((cmd, len(payload))) + payload
        crc = crc8_smbus(body)
        if self.corrupt_replies > 0:
            self.corrupt_replies -= 1
            crc ^= 0x5A
        self.send(bytes((SYNC,)) + body + bytes((crc,)))
