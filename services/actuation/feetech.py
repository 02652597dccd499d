"""Feetech STS/SCS serial-bus servos: packet codec, register table and a bus on a serial link.

Packets (Feetech's "communication protocol", shared by the STS3215 of the SO-100/SO-101 arms):

    instruction  0xFF 0xFF id len instr params... chk     len = len(params) + 2
    status       0xFF 0xFF id len error params... chk     len = len(params) + 2
    chk          = ~(id + len + instr/error + sum(params)) & 0xFF

Instructions used: PING 0x01, READ 0x02 (address, count), WRITE 0x03 (address, data...) and
SYNC_WRITE 0x83 to the broadcast id 0xFE (address, data length, then id + data per servo; no
status reply). Multi-byte registers are little endian on STS/SMS servos and big endian on SCS.
Every status packet is checked: header, id, length, checksum and the servo's error bits.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Literal, TypeAlias

from services.core.serial_link import LinkCorruptError, LinkError, SerialLink

Series: TypeAlias = Literal["sts", "scs"]

HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
PING = 0x01
READ = 0x02
WRITE = 0x03
SYNC_WRITE = 0x83
MAX_ID = 0xFD


@dataclass(frozen=True, slots=True)
class Register:
    """One entry of a servo's control table."""

    address: int
    size: int  # bytes
    writable: bool
    doc: str  # unit and meaning


# STS/SMS control table (Feetech STS3215 manual; the same addresses as LeRobot's table).
STS_REGISTERS: dict[str, Register] = {
    "model_number": Register(3, 2, False, "model (777 = STS3215)"),
    "id": Register(5, 1, True, "bus id, EEPROM"),
    "baud_rate": Register(6, 1, True, "0 = 1 Mbit/s, EEPROM"),
    "min_position_limit": Register(9, 2, True, "steps, EEPROM"),
    "max_position_limit": Register(11, 2, True, "steps, EEPROM"),
    "torque_enable": Register(0x28, 1, True, "1 = hold the goal, 0 = limp"),
    "acceleration": Register(0x29, 1, True, "100 steps/s² per unit, 0 = maximum"),
    "goal_position": Register(0x2A, 2, True, "steps, 4096 per turn"),
    "goal_time": Register(0x2C, 2, True, "ms to reach the goal, 0 = use goal_speed"),
    "goal_speed": Register(0x2E, 2, True, "steps/s, 0 = maximum"),
    "torque_limit": Register(0x30, 2, True, "0.1 % of stall torque"),
    "lock": Register(0x37, 1, True, "1 = EEPROM write-protected"),
    "present_position": Register(0x38, 2, False, "steps"),
    "present_speed": Register(0x3A, 2, False, "steps/s, bit 15 = sign"),
    "present_load": Register(0x3C, 2, False, "0.1 %, bit 10 = direction"),
    "present_voltage": Register(0x3E, 1, False, "0.1 V"),
    "present_temperature": Register(0x3F, 1, False, "°C"),
    "moving": Register(0x42, 1, False, "1 while moving"),
}
REG = STS_REGISTERS

# Bits of the error byte of a status packet (Feetech SCServo SDK).
STATUS_ERRORS: dict[int, str] = {
    0x01: "input voltage out of range",
    0x02: "angle sensor error",
    0x04: "overheat",
    0x08: "overcurrent",
    0x20: "overload",
}
RESOLUTION: dict[Series, int] = {"sts": 4096, "scs": 1024}  # steps per turn
BYTE_ORDER: dict[Series, Literal["little", "big"]] = {"sts": "little", "scs": "big"}


class FeetechChecksumError(LinkCorruptError):
    """A status packet failed its checksum or framing."""


class FeetechServoError(LinkError):
    """A servo answered with error bits set (overload, overheat, …)."""

    def __init__(self, servo_id: int, error: int) -> None:
        """Describe the error bits of one servo."""
        super().__init__(f"servo {servo_id} reports {describe_error(error)}")
        self.servo_id = servo_id
        self.error = error


# -- codec (pure) -----------------------------------------------------------------------------
def checksum(body: bytes | Iterable[int]) -> int:
    """~(sum of id, length, instruction/error and parameters) & 0xFF."""
    return ~sum(body) & 0xFF


def describe_error(error: int) -> str:
    """The error byte of a status packet as text."""
    names = [name for bit, name in STATUS_ERRORS.items() if error & bit]
    unknown = error & ~sum(STATUS_ERRORS)
    if unknown:
        names.append(f"error bits 0x{unknown:02X}")
    return ", ".join(names) if names else "no error"


def encode_packet(servo_id: int, instruction: int, params: bytes = b"") -> bytes:
    """An instruction packet."""
    if not 0 <= servo_id <= BROADCAST_ID:
        raise ValueError(f"servo id must be in [0, {BROADCAST_ID}], got {servo_id}")
    body = bytes((servo_id, len(params) + 2, instruction)) + params
    if body[1] > 0xFF:
        raise ValueError(f"too many parameters ({len(params)})")
    return HEADER + body + bytes((checksum(body),))


def encode_word(value: int, size: int, order: Literal["little", "big"] = "little") -> bytes:
    """An unsigned register value of `size` bytes."""
    if not 0 <= value < 1 << (8 * size):
        raise ValueError(f"value {value} does not fit in {size} byte(s)")
    return value.to_bytes(size, order)


def ping_packet(servo_id: int) -> bytes:
    """PING one servo."""
    return encode_packet(servo_id, PING)


def read_packet(servo_id: int, address: int, count: int) -> bytes:
    """READ `count` bytes from `address`."""
    return encode_packet(servo_id, READ, bytes((address, count)))


def write_packet(servo_id: int, address: int, data: bytes) -> bytes:
    """WRITE bytes at `address`."""
    return encode_packet(servo_id, WRITE, bytes((address,)) + data)


def sync_write_packet(address: int, length: int, data: Mapping[int, bytes]) -> bytes:
    """SYNC_WRITE `length` bytes at `address` of each servo, in one broadcast packet."""
    params = bytearray((address, length))
    for servo_id, chunk in data.items():
        if len(chunk) != length:
            raise ValueError(f"servo {servo_id}: expected {length} bytes, got {len(chunk)}")
        params.append(servo_id)
        params.extend(chunk)
    return encode_packet(BROADCAST_ID, SYNC_WRITE, bytes(params))


@dataclass(frozen=True, slots=True)
class Status:
    """A decoded status packet."""

    servo_id: int
    error: int
    params: bytes


def decode_status(packet: bytes) -> Status:
    """Decode and verify a complete status packet; raise `FeetechChecksumError` if corrupt."""
    if len(packet) < 6 or packet[:2] != HEADER:
        raise FeetechChecksumError(f"not a status packet: {packet.hex(' ')}")
    length = packet[3]
    if len(packet) != length + 4:
        raise FeetechChecksumError(f"status length {length} does not match {packet.hex(' ')}")
    body, chk = packet[2:-1], packet[-1]
    if checksum(body) != chk:
        raise FeetechChecksumError(
            f"status packet from servo {packet[2]} failed its checksum "
            f"(got 0x{chk:02X}, expected 0x{checksum(body):02X})"
        )
    return Status(packet[2], packet[4], bytes(packet[5:-1]))


# -- bus ----------------------------------------------------------------------------------------
class FeetechBus:
    """Request/response on a half-duplex servo bus; every failure raises a `LinkError`."""

    def __init__(self, link: SerialLink, series: Series = "sts") -> None:
        """Talk to the servos behind `link` (opened by the caller)."""
        self.link = link
        self.order = BYTE_ORDER[series]

    def _status(self, request: bytes, servo_id: int, what: str) -> Status:
        self.link.discard_input()
        self.link.write(request)
        head = self.link.read_exact(4, f"status from servo {servo_id} to {what}")
        if head[:2] != HEADER or head[2] != servo_id or not 2 <= head[3] <= 0xFF:
            raise FeetechChecksumError(
                f"bad status header {head.hex(' ')} from servo {servo_id} to {what}"
            )
        rest = self.link.read_exact(head[3], f"status from servo {servo_id} to {what}")
        status = decode_status(head + rest)
        if status.error:
            raise FeetechServoError(servo_id, status.error)
        return status

    def ping(self, servo_id: int) -> None:
        """PING; raise if the servo is silent, corrupt or reports an error."""
        self._status(ping_packet(servo_id), servo_id, "PING")

    def read(self, servo_id: int, address: int, count: int) -> bytes:
        """READ `count` bytes at `address`."""
        status = self._status(read_packet(servo_id, address, count), servo_id, "READ")
        if len(status.params) != count:
            raise FeetechChecksumError(
                f"servo {servo_id} returned {len(status.params)} bytes, {count} were asked"
            )
        return status.params

    def write(self, servo_id: int, address: int, data: bytes) -> None:
        """WRITE and wait for the servo's acknowledgement."""
        self._status(write_packet(servo_id, address, data), servo_id, "WRITE")

    def sync_write(self, address: int, length: int, data: Mapping[int, bytes]) -> None:
        """SYNC_WRITE (broadcast, no reply: a broken bus shows on the next read)."""
        self.link.write(sync_write_packet(address, length, data))

    # -- register helpers ----------------------------------------------------------------------
    def read_register(self, servo_id: int, name: str) -> int:
        """One register by name (see `STS_REGISTERS`)."""
        reg = REG[name]
        return int.from_bytes(self.read(servo_id, reg.address, reg.size), self.order)

    def write_register(self, servo_id: int, name: str, value: int) -> None:
        """One writable register by name."""
        reg = REG[name]
        if not reg.writable:
            raise ValueError(f"register {name} is read-only")
        self.write(servo_id, reg.address, encode_word(value, reg.size, self.order))

    def read_positions(self, ids: Iterable[int]) -> tuple[int, ...]:
        """Present positions (steps), one READ per servo."""
        return tuple(self.read_register(i, "present_position") for i in ids)

    def write_goals(self, goals: Mapping[int, int], speed: int) -> None:
        """Goal position, goal time 0 and goal speed of every servo in one SYNC_WRITE."""
        size = REG["goal_position"].size + REG["goal_time"].size + REG["goal_speed"].size
        data = {
            i: encode_word(pos, 2, self.order)
            + encode_word(0, 2, self.order)
            + encode_word(speed, 2, self.order)
            for i, pos in goals.items()
        }
        self.sync_write(REG["goal_position"].address, size, data)

    def set_torque(self, ids: Iterable[int], enabled: bool) -> None:
        """Torque on (hold the goal) or off (limp, movable by hand) for each servo."""
        for i in ids:
            self.write_register(i, "torque_enable", 1 if enabled else 0)
