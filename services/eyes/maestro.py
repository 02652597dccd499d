"""Pololu Maestro USB servo controller: compact serial protocol and the eyes driver.

The Maestro's "Command Port" (first USB virtual COM port, e.g. /dev/ttyACM0) accepts the compact
protocol when its serial mode is "USB Dual Port" (the factory setting). Commands used here:

    Set Target        0x84, channel, target & 0x7F, (target >> 7) & 0x7F   target in ¼ µs
    Set Speed         0x87, channel, speed & 0x7F,  (speed >> 7) & 0x7F    ¼ µs per 10 ms
    Set Acceleration  0x89, channel, accel & 0x7F,  (accel >> 7) & 0x7F    ¼ µs per 10 ms per 80 ms
    Get Position      0x90, channel             → 2 bytes, little endian, ¼ µs
    Get Errors        0xA1                      → 2 bytes, little endian; clears the errors

Set Target has no reply, so every send is followed by Get Errors: its answer proves the Maestro
is alive and reports protocol errors (after any error the Maestro itself moves its servos to
their home positions, so the driver writes the targets again).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from services.core.serial_link import LinkConfig
from services.eyes.serial_servo import SerialServoDriver
from services.model.servos import ServoTargets

SET_TARGET = 0x84
SET_SPEED = 0x87
SET_ACCELERATION = 0x89
GET_POSITION = 0x90
GET_ERRORS = 0xA1
MAX_VALUE = 0x3FFF  # 14-bit data values
MAX_CHANNELS = 24  # the Mini Maestro 24 has the most channels

# Bit → meaning of the Maestro error register (user's guide, "Errors").
ERROR_BITS: dict[int, str] = {
    0: "serial signal error (baud rate mismatch?)",
    1: "serial overrun error",
    2: "serial RX buffer full",
    3: "serial CRC error",
    4: "serial protocol error",
    5: "serial timeout",
    6: "script stack error",
    7: "script call stack error",
    8: "script program counter error",
}


# -- codec (pure) -----------------------------------------------------------------------------
def _value_command(command: int, channel: int, value: int) -> bytes:
    if not 0 <= channel < MAX_CHANNELS:
        raise ValueError(f"Maestro channel must be in [0, {MAX_CHANNELS}), got {channel}")
    if not 0 <= value <= MAX_VALUE:
        raise ValueError(f"Maestro value must be in [0, {MAX_VALUE}], got {value}")
    return bytes((command, channel, value & 0x7F, (value >> 7) & 0x7F))


def quarter_us(pulse_us: float) -> int:
    """A pulse width (µs) in the Maestro's target unit (¼ µs), rounded."""
    return round(pulse_us * 4.0)


def set_target(channel: int, target_qus: int) -> bytes:
    """Set Target: pulse width in ¼ µs (0 stops the pulses)."""
    return _value_command(SET_TARGET, channel, target_qus)


def set_speed(channel: int, speed: int) -> bytes:
    """Set Speed: limit in ¼ µs per 10 ms (0 = unlimited)."""
    return _value_command(SET_SPEED, channel, speed)


def set_acceleration(channel: int, acceleration: int) -> bytes:
    """Set Acceleration: limit in ¼ µs per 10 ms per 80 ms (0 = unlimited)."""
    return _value_command(SET_ACCELERATION, channel, acceleration)


def get_position(channel: int) -> bytes:
    """Get Position request (the reply is 2 bytes, little endian, ¼ µs)."""
    if not 0 <= channel < MAX_CHANNELS:
        raise ValueError(f"Maestro channel must be in [0, {MAX_CHANNELS}), got {channel}")
    return bytes((GET_POSITION, channel))


def decode_u16(reply: bytes) -> int:
    """A 2-byte little-endian reply (Get Position, Get Errors)."""
    if len(reply) != 2:
        raise ValueError(f"a Maestro reply has 2 bytes, got {len(reply)}")
    return reply[0] | (reply[1] << 8)


def describe_errors(bits: int) -> str:
    """The error register as text, e.g. "0x0010 (serial protocol error)"."""
    names = [ERROR_BITS.get(i, f"bit {i}") for i in range(16) if bits >> i & 1]
    return f"0x{bits:04X} ({', '.join(names)})"


# -- configuration ----------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class MaestroConfig:
    """How the four eye servos are wired to a Maestro."""

    # Maestro channels of (left pan, left tilt, right pan, right tilt); distinct, each in 0–23.
    channels: tuple[int, int, int, int] = (0, 1, 2, 3)
    # Baud rate (bit/s); ignored by the USB virtual COM port, used on the TTL serial pins.
    baudrate: int = 9600
    # Speed limit per channel (¼ µs per 10 ms, 0 = unlimited). 0 lets the gaze snap, as the
    # paper's eyes do; e.g. 40 = 100 µs per 10 ms ≈ 90° in 0.1 s at 2000 µs / 180°.
    speed: int = 0
    # Acceleration limit per channel (¼ µs per 10 ms per 80 ms, 0 = unlimited); 0–255.
    acceleration: int = 0
    link: LinkConfig = field(default_factory=LinkConfig)  # timeouts and reconnect backoff

    def __post_init__(self) -> None:
        if len(self.channels) != 4 or len(set(self.channels)) != 4:
            raise ValueError(f"MaestroConfig.channels needs 4 distinct channels: {self.channels}")
        if not all(0 <= c < MAX_CHANNELS for c in self.channels):
            raise ValueError(f"MaestroConfig.channels must be < {MAX_CHANNELS}: {self.channels}")
        if self.baudrate <= 0:
            raise ValueError(f"MaestroConfig.baudrate must be > 0, got {self.baudrate}")
        if not 0 <= self.speed <= MAX_VALUE:
            raise ValueError(f"MaestroConfig.speed must be in [0, {MAX_VALUE}], got {self.speed}")
        if not 0 <= self.acceleration <= 255:
            raise ValueError(f"MaestroConfig.acceleration must be in [0, 255]: {self.acceleration}")


# -- driver -----------------------------------------------------------------------------------
class MaestroServoDriver(SerialServoDriver[MaestroConfig]):
    """The eyes on a Pololu Maestro (Micro Maestro 6 or any Mini Maestro)."""

    device = "Maestro"
    hint = (
        "check that the port is the Maestro's Command Port (the first of its two ports) and "
        "that its serial mode is USB Dual Port (Maestro Control Center → Serial Settings)"
    )

    @classmethod
    def default_config(cls) -> MaestroConfig:
        """The controller's configuration when none is given: the defaults."""
        return MaestroConfig()

    def encode_targets(self, targets: ServoTargets) -> bytes:
        """The Set Target commands for four targets, in `SERVO_NAMES` order."""
        pairs = zip(self.config.channels, targets.pulses_us, strict=True)
        return b"".join(set_target(ch, quarter_us(p)) for ch, p in pairs)

    def read_positions_us(self) -> tuple[float, ...]:
        """The pulse each eye channel outputs now (µs), via Get Position (for bench tests)."""
        out = []
        for ch in self.config.channels:
            reply = self.link.transact(get_position(ch), 2, f"Get Position {ch} reply")
            out.append(decode_u16(reply) / 4.0)
        return tuple(out)

    def _errors(self) -> str | None:
        bits = decode_u16(self.link.transact(bytes((GET_ERRORS,)), 2, "Get Errors reply"))
        return None if bits == 0 else f"error register {describe_errors(bits)}"

    def _initialise(self) -> None:
        c = self.config
        self.link.discard_input()
        self.link.write(
            b"".join(
                set_speed(ch, c.speed) + set_acceleration(ch, c.acceleration) for ch in c.channels
            )
        )
        self._errors()  # proves the Maestro answers and clears errors from before we opened

    def _write_targets(self, targets: ServoTargets) -> str | None:
        self.link.write(self.encode_targets(targets))
        return self._errors()

    def _probe(self) -> str | None:
        return self._errors()
