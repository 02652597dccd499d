"""A bus of Feetech STS servos on a pty: packets, a register table per servo, status replies.

Written from the Feetech protocol description, independently of the driver: the register map
below is this emulator's own copy (STS3215 manual). Each servo is a 256-byte memory initialised
from `REGISTER_MAP`; PING, READ, WRITE and SYNC_WRITE are answered like a servo with
"Response_Status_Level" 1 (status after every non-broadcast instruction). Packets with a bad
checksum are ignored (no reply), as real servos do.

Physics, kept minimal: with torque on, the present position jumps to the goal, clamped to the
servo's angle limits (`min/max_position_limit`, EEPROM; factory 0–4095); with torque off it
stays where `move_by_hand` puts it.

Faults to inject: `silent` (nothing answers), `silent_ids` (those servos are unplugged),
`corrupt_replies` (the next n status packets carry a wrong checksum), `error_bits` per id (set in
every status packet of that servo, e.g. 0x20 overload), `block(id)` (the horn is jammed: the
present position no longer follows the goal).
"""

from __future__ import annotations

from pathlib import Path

from services.actuation.arm_path import ArmPoses
from tests.emulators.pty_device import PtyDevice

# The arm the Feetech tests drive: three servos and five distinct, reachable poses.
IDS = (1, 2, 3)
POSES = ArmPoses(
    home=(2048, 2048, 2048),
    above_red=(2448, 2148, 1948),
    press_red=(2448, 2348, 1848),
    above_blue=(1648, 2148, 1948),
    press_blue=(1648, 2348, 1848),
)
# The same arm over a table of N boxes by option name: the paper's two, then a third spoke
# straight ahead of home for green (distinct from every other pose, within the servos' limits).
NAMES: dict[int, tuple[str, ...]] = {2: ("red", "blue"), 3: ("red", "blue", "green")}
POSES_BY_N: dict[int, ArmPoses] = {
    2: POSES,
    3: ArmPoses(**POSES.table(), above_green=(2048, 2448, 1748), press_green=(2048, 2648, 1648)),
}

# name: (address, size, writable, initial value)
REGISTER_MAP: dict[str, tuple[int, int, bool, int]] = {
    "model_number": (3, 2, False, 777),  # STS3215
    "id": (5, 1, True, 0),  # set per servo
    "response_status_level": (8, 1, True, 1),
    "min_position_limit": (9, 2, True, 0),
    "max_position_limit": (11, 2, True, 4095),
    "torque_enable": (0x28, 1, True, 0),
    "acceleration": (0x29, 1, True, 0),
    "goal_position": (0x2A, 2, True, 2048),
    "goal_time": (0x2C, 2, True, 0),
    "goal_speed": (0x2E, 2, True, 0),
    "lock": (0x37, 1, True, 1),
    "present_position": (0x38, 2, False, 2048),
    "present_speed": (0x3A, 2, False, 0),
    "present_voltage": (0x3E, 1, False, 74),  # 7.4 V
    "present_temperature": (0x3F, 1, False, 30),
    "moving": (0x42, 1, False, 0),
}
READ_ONLY = {
    addr + k
    for addr, size, writable, _ in REGISTER_MAP.values()
    if not writable
    for k in range(size)
}


def chk(body: bytes) -> int:
    """Feetech checksum: bitwise NOT of the byte sum."""
    return (~sum(body)) & 0xFF


class Servo:
    """One servo's memory."""

    def __init__(self, servo_id: int, position: int = 2048) -> None:
        self.mem = bytearray(256)
        for addr, size, _, value in REGISTER_MAP.values():
            self.mem[addr : addr + size] = value.to_bytes(size, "little")
        self.mem[5] = servo_id
        self.set("present_position", position)
        self.set("goal_position", position)
        self.blocked = False  # a jammed horn: the present position stays where it is

    def get(self, name: str) -> int:
        """A register's value."""
        addr, size, _, _ = REGISTER_MAP[name]
        return int.from_bytes(self.mem[addr : addr + size], "little")

    def set(self, name: str, value: int) -> None:
        """Set a register, read-only ones included (the servo's own sensors)."""
        addr, size, _, _ = REGISTER_MAP[name]
        self.mem[addr : addr + size] = value.to_bytes(size, "little")

    def write(self, addr: int, data: bytes) -> None:
        """A host write: read-only bytes are left alone; torque on makes it track the goal."""
        for k, b in enumerate(data):
            if addr + k < 256 and addr + k not in READ_ONLY:
                self.mem[addr + k] = b
        if self.get("torque_enable") and not self.blocked:
            lo, hi = self.get("min_position_limit"), self.get("max_position_limit")
            goal = self.get("goal_position")
            self.set("present_position", min(max(goal, lo), hi) if lo < hi else goal)


class FeetechBusEmulator(PtyDevice):
    """Several servos on one half-duplex bus."""

    def __init__(self, positions: dict[int, int], link_dir: Path | None = None) -> None:
        super().__init__(link_dir, "ttyUSB-arm")
        self._initial = dict(positions)
        self.servos = {i: Servo(i, p) for i, p in positions.items()}
        self.silent_ids: set[int] = set()
        self.corrupt_replies = 0
        self.error_bits: dict[int, int] = {}
        self.packets: list[tuple[int, int, bytes]] = []  # (id, instruction, params) received
        self.goal_history: list[dict[int, int]] = []  # goal positions after each SYNC_WRITE
        self._buf = bytearray()

    def on_replug(self) -> None:
        """USB adapter re-plugged: the servos keep power and state; the parser restarts."""
        self._buf.clear()

    def move_by_hand(self, servo_id: int, position: int) -> None:
        """Move a servo with torque off (calibration)."""
        self.servos[servo_id].set("present_position", position)

    def set_limits(self, servo_id: int, low: int, high: int) -> None:
        """Write a servo's angle limits (as the Feetech software would, into EEPROM)."""
        with self._lock:
            self.servos[servo_id].set("min_position_limit", low)
            self.servos[servo_id].set("max_position_limit", high)

    def block(self, servo_id: int) -> None:
        """Jam a servo's horn: it keeps its present position whatever the goal."""
        with self._lock:
            self.servos[servo_id].blocked = True

    def positions(self) -> dict[int, int]:
        """Present positions of all servos."""
        return {i: s.get("present_position") for i, s in self.servos.items()}

    def goals(self) -> dict[int, int]:
        """Goal positions of all servos."""
        return {i: s.get("goal_position") for i, s in self.servos.items()}

    def feed(self, data: bytes) -> None:
        """Split the byte stream into packets (resync on 0xFF 0xFF)."""
        self._buf.extend(data)
        while True:
            start = self._buf.find(b"\xff\xff")
            if start < 0:
                self._buf.clear()
                return
            del self._buf[:start]
            if len(self._buf) < 4:
                return
            length = self._buf[3]
            if len(self._buf) < 4 + length:
                return
            packet = bytes(self._buf[: 4 + length])
            del self._buf[: 4 + length]
            if length >= 2 and chk(packet[2:-1]) == packet[-1]:
                self._execute(packet[2], packet[4], packet[5:-1])

    def _execute(self, servo_id: int, instr: int, params: bytes) -> None:
        self.packets.append((servo_id, instr, params))
        if servo_id == 0xFE:
            if instr == 0x83:  # SYNC_WRITE: addr, len, (id, data*len)*
                addr, n = params[0], params[1]
                for k in range(2, len(params), n + 1):
                    sid = params[k]
                    if sid in self.servos and sid not in self.silent_ids:
                        self.servos[sid].write(addr, params[k + 1 : k + 1 + n])
                self.goal_history.append(self.goals())
            return
        servo = self.servos.get(servo_id)
        if servo is None or servo_id in self.silent_ids:
            return
        if instr == 0x01:  # PING
            self._status(servo_id, b"")
        elif instr == 0x02:  # READ: addr, count
            addr, n = params[0], params[1]
            self._status(servo_id, bytes(servo.mem[addr : addr + n]))
        elif instr == 0x03:  # WRITE: addr, data...
            servo.write(params[0], params[1:])
            self._status(servo_id, b"")

    def _status(self, servo_id: int, params: bytes) -> None:
        body = bytes((servo_id, len(params) + 2, self.error_bits.get(servo_id, 0))) + params
        c = chk(body)
        if self.corrupt_replies > 0:
            self.corrupt_replies -= 1
            c ^= 0xFF
        self.send(b"\xff\xff" + body + bytes((c,)))
