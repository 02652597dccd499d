"""The eyes on an Arduino running `firmware/eyes/eyes.ino`: framed, checksummed serial protocol.

The protocol is specified in `firmware/eyes/PROTOCOL.md`; in short, every frame in either
direction is

    0xA5 | cmd | len | payload (len bytes) | crc8(cmd, len, payload)

with CRC-8 polynomial 0x07, initial value 0 (CRC-8/SMBUS). The host sends PING (0x01),
SET_PULSES (0x02: four uint16 little-endian pulse widths in µs, in `SERVO_NAMES` order) and
GET_PULSES (0x03); the sketch answers each with `cmd | 0x80` (SET_PULSES and GET_PULSES echo the
pulses it applies) or NAK (0x7F, one error byte). Every send is therefore confirmed.

Opening the port resets most Arduinos (DTR), and the bootloader ignores bytes for about 1–2 s:
`connect()` and every reopen ping until the sketch answers, for up to `boot_wait_s`.
"""

from __future__ import annotations

import logging
import math
import struct
from dataclasses import dataclass, field

from services.core.serial_link import LinkConfig, LinkCorruptError, LinkTimeoutError
from services.eyes.serial_servo import SerialServoDriver
from services.model.servos import ServoTargets

log = logging.getLogger(__name__)

SYNC = 0xA5
PING = 0x01
SET_PULSES = 0x02
GET_PULSES = 0x03
REPLY = 0x80  # reply command = request | REPLY
NAK = 0x7F
MAX_PAYLOAD = 16
PROTOCOL_VERSION = 1
N_SERVOS = 4
# NAK error byte → meaning (PROTOCOL.md).
NAK_CODES: dict[int, str] = {
    1: "bad checksum",
    2: "unknown command",
    3: "bad payload length",
}


# -- codec (pure) -----------------------------------------------------------------------------
def crc8(data: bytes) -> int:
    """CRC-8/SMBUS: polynomial 0x07, initial 0, no reflection, no final xor."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def encode_frame(cmd: int, payload: bytes = b"") -> bytes:
    """One frame: sync, command, length, payload, CRC."""
    if not 0 <= cmd <= 0xFF:
        raise ValueError(f"command must be a byte, got {cmd}")
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload is at most {MAX_PAYLOAD} bytes, got {len(payload)}")
    body = bytes((cmd, len(payload))) + payload
    return bytes((SYNC,)) + body + bytes((crc8(body),))


def encode_pulses(pulses_us: tuple[float, ...]) -> bytes:
    """Four pulse widths (µs), rounded, as uint16 little endian."""
    if len(pulses_us) != N_SERVOS or not all(math.isfinite(p) for p in pulses_us):
        raise ValueError(f"need {N_SERVOS} finite pulse widths, got {pulses_us}")
    values = [round(p) for p in pulses_us]
    if not all(0 <= v <= 0xFFFF for v in values):
        raise ValueError(f"pulse widths must fit in 16 bits, got {values}")
    return struct.pack("<4H", *values)


def decode_pulses(payload: bytes) -> tuple[int, ...]:
    """Four uint16 little-endian pulse widths (µs)."""
    if len(payload) != 2 * N_SERVOS:
        raise ValueError(f"a pulses payload has {2 * N_SERVOS} bytes, got {len(payload)}")
    return struct.unpack("<4H", payload)


# -- configuration ----------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class ArduinoEyesConfig:
    """The serial side of the Arduino eyes sketch."""

    # Baud rate (bit/s); must match `BAUD` in eyes.ino.
    baudrate: int = 115200
    # After opening the port, how long to keep pinging while the board resets and its
    # bootloader runs (s); >= 0. 0 for boards that do not reset on open.
    boot_wait_s: float = 3.0
    link: LinkConfig = field(default_factory=LinkConfig)  # timeouts and reconnect backoff

    def __post_init__(self) -> None:
        if self.baudrate <= 0:
            raise ValueError(f"ArduinoEyesConfig.baudrate must be > 0, got {self.baudrate}")
        if not math.isfinite(self.boot_wait_s) or self.boot_wait_s < 0:
            raise ValueError(f"ArduinoEyesConfig.boot_wait_s must be >= 0, got {self.boot_wait_s}")


# -- driver -----------------------------------------------------------------------------------
class ArduinoServoDriver(SerialServoDriver[ArduinoEyesConfig]):
    """The eyes on an Arduino with four hobby servos (firmware/eyes/eyes.ino)."""

    device = "Arduino eyes"
    hint = "check that eyes.ino is flashed, the --port path and that both sides use 115200 baud"
    #: The pulses the sketch echoed at its latest initialisation (None before the first).
    firmware_pulses: tuple[int, ...] | None = None

    @classmethod
    def default_config(cls) -> ArduinoEyesConfig:
        """The controller's configuration when none is given: the defaults."""
        return ArduinoEyesConfig()

    def request(self, cmd: int, payload: bytes = b"", *, counted: bool = True) -> bytes:
        """Send one frame and return the reply's payload; raise on NAK, CRC or silence."""
        self.link.discard_input()
        self.link.write(encode_frame(cmd, payload))
        head = self.link.read_exact(3, f"reply to command 0x{cmd:02X}", counted=counted)
        if head[0] != SYNC or head[2] > MAX_PAYLOAD:
            raise LinkCorruptError(f"garbled reply header {head.hex(' ')} to command 0x{cmd:02X}")
        rest = self.link.read_exact(head[2] + 1, f"reply to command 0x{cmd:02X}")
        body, crc = head[1:] + rest[:-1], rest[-1]
        if crc8(body) != crc:
            raise LinkCorruptError(
                f"reply to command 0x{cmd:02X} failed its checksum "
                f"(got 0x{crc:02X}, expected 0x{crc8(body):02X})"
            )
        reply_cmd, reply = body[0], body[2:]
        if reply_cmd == NAK:
            code = reply[0] if reply else 0
            raise LinkCorruptError(
                f"the sketch refused command 0x{cmd:02X}: {NAK_CODES.get(code, f'error {code}')}"
            )
        if reply_cmd != cmd | REPLY:
            raise LinkCorruptError(f"reply 0x{reply_cmd:02X} does not match command 0x{cmd:02X}")
        return reply

    def read_pulses_us(self) -> tuple[int, ...]:
        """The pulses the sketch outputs now (µs), via GET_PULSES (for bench tests)."""
        return decode_pulses(self.request(GET_PULSES))

    def _initialise(self) -> None:
        deadline = self.link.clock() + self.config.boot_wait_s
        while True:
            try:
                reply = self.request(PING, counted=False)
                break
            except LinkTimeoutError:
                if self.link.clock() >= deadline:
                    raise
        if len(reply) < 2 or reply[0] != PROTOCOL_VERSION or reply[1] != N_SERVOS:
            raise LinkCorruptError(
                f"the sketch speaks protocol {reply[:1].hex()} with {reply[1:2].hex()} servos; "
                f"this driver needs protocol {PROTOCOL_VERSION} with {N_SERVOS}: flash eyes.ino"
            )

    def _write_targets(self, targets: ServoTargets) -> str | None:
        sent = encode_pulses(targets.pulses_us)
        echoed = self.request(SET_PULSES, sent)
        if len(echoed) != len(sent):
            raise LinkCorruptError(f"SET_PULSES echo has {len(echoed)} bytes, expected {len(sent)}")
        self.firmware_pulses = decode_pulses(echoed)
        if echoed != sent:
            log.warning(
                "the sketch clamped pulses %s to %s: widen MIN/MAX_PULSE_US in eyes.ino or "
                "narrow the calibration",
                decode_pulses(sent),
                self.firmware_pulses,
            )
        return None

    def _probe(self) -> str | None:
        self.request(PING)
        return None
