"""A Pololu Maestro servo controller speaking the compact serial protocol, on a pty.

Implemented (Maestro user's guide, "Serial servo commands"): a command byte has its top bit set,
data bytes do not; 14-bit values travel as low 7 bits then high 7 bits.

    Set Target        0x84, channel, target lo, target hi     (quarter-µs; 0 = pulses off)
    Set Speed         0x87, channel, speed lo, speed hi       (0.25 µs / 10 ms; 0 = unlimited)
    Set Acceleration  0x89, channel, accel lo, accel hi       (0.25 µs / 10 ms / 80 ms)
    Get Position      0x90, channel            → pos lo, pos hi (bytes, little endian)
    Get Errors        0xA1                     → err lo, err hi; reading clears the errors

A data byte where a command byte is expected, a command byte inside a packet, an unknown command
or a channel beyond the device's count sets "serial protocol error" (bit 4), as the real device
does. Targets are clamped to the channel's configured range (the Maestro Control Center's
Min/Max). Positions jump to the target at once (no speed/acceleration ramp).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tests.emulators.pty_device import PtyDevice

SET_TARGET = 0x84
SET_SPEED = 0x87
SET_ACCELERATION = 0x89
GET_POSITION = 0x90
GET_ERRORS = 0xA1
# Command byte → number of data bytes.
COMMANDS: dict[int, int] = {
    SET_TARGET: 3,
    SET_SPEED: 3,
    SET_ACCELERATION: 3,
    GET_POSITION: 1,
    GET_ERRORS: 0,
}
ERR_PROTOCOL = 1 << 4


@dataclass
class Channel:
    """One servo channel's state."""

    target: int = 0  # quarter-µs; 0 = no pulses
    speed: int = 0
    acceleration: int = 0
    min_qus: int = 2000  # configured range (quarter-µs); the factory default is 3968–8000
    max_qus: int = 10000

    @property
    def position(self) -> int:
        """The output pulse (quarter-µs): the target, reached instantly."""
        return self.target


class MaestroEmulator(PtyDevice):
    """A Maestro with `n_channels` channels (6 for the Micro Maestro)."""

    def __init__(self, n_channels: int = 6, link_dir: Path | None = None) -> None:
        super().__init__(link_dir, "ttyACM-maestro")
        self.channels = [Channel() for _ in range(n_channels)]
        self.errors = 0
        self.commands: list[tuple[int, ...]] = []  # every complete packet, in order
        self._packet: list[int] = []

    def on_replug(self) -> None:
        """A power cycle: targets off, errors and the parser cleared."""
        self.channels = [Channel() for _ in self.channels]
        self.errors = 0
        self._packet = []

    def inject_errors(self, bits: int) -> None:
        """Raise error bits, as line noise or a script bug would (thread-safe)."""
        with self._lock:
            self.errors |= bits

    def feed(self, data: bytes) -> None:
        """Parse compact-protocol packets byte by byte."""
        for b in data:
            if b & 0x80:
                if self._packet:  # a command interrupted an unfinished packet
                    self.errors |= ERR_PROTOCOL
                self._packet = [b]
                if b not in COMMANDS:
                    self.errors |= ERR_PROTOCOL
                    self._packet = []
                    continue
            elif not self._packet:
                self.errors |= ERR_PROTOCOL  # a data byte with no command
                continue
            else:
                self._packet.append(b)
            if len(self._packet) == 1 + COMMANDS[self._packet[0]]:
                packet, self._packet = tuple(self._packet), []
                self.commands.append(packet)
                self._execute(packet)

    def _execute(self, p: tuple[int, ...]) -> None:
        cmd = p[0]
        if cmd == GET_ERRORS:
            errors, self.errors = self.errors, 0  # cleared before the reply leaves
            self.send(bytes((errors & 0xFF, (errors >> 8) & 0xFF)))
            return
        channel = p[1]
        if channel >= len(self.channels):
            self.errors |= ERR_PROTOCOL
            return
        ch = self.channels[channel]
        if cmd == GET_POSITION:
            pos = ch.position
            self.send(bytes((pos & 0xFF, pos >> 8)))
            return
        value = p[2] | (p[3] << 7)
        if cmd == SET_TARGET:
            ch.target = 0 if value == 0 else min(max(value, ch.min_qus), ch.max_qus)
        elif cmd == SET_SPEED:
            ch.speed = value
        elif cmd == SET_ACCELERATION:
            ch.acceleration = value

    def targets_us(self, channels: tuple[int, ...] = (0, 1, 2, 3)) -> tuple[float, ...]:
        """Current targets of some channels, in µs."""
        return tuple(self.channels[c].target / 4.0 for c in channels)
