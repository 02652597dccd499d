"""The message contract: every payload on the wire, its msgpack codec and its strict validation.

A message is a frozen dataclass. On the wire it is a msgpack map holding the schema version `v`,
the sequence number `seq` and the source timestamp `t_ns` (ns, the publisher's clock: wall
clock in real time, the shared simulated clock under `--sim`), plus the message's own fields.

`decode(cls, payload)` checks everything a peer could get wrong — msgpack syntax, schema
version, missing or unknown fields, types, finiteness, ranges, shapes — and raises one
`MessageError` whose text says what was wrong, so a service can log one line and carry on.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal, TypeVar

import msgpack

SCHEMA_VERSION = 1
MAX_PAYLOAD_BYTES = 64 * 1024  # no message of ours comes near this; larger is garbage
MAX_LANDMARKS = 64

Vec2 = tuple[float, float]
M = TypeVar("M", bound="Message")


class MessageError(ValueError):
    """A payload failed to decode or validate; the text says which field and why."""


def _rng(lo: float, hi: float) -> dict[str, Any]:
    return {"range": (lo, hi)}


@dataclass(frozen=True, slots=True)
class Message:
    """Base of every message: sequence number and source timestamp."""

    KIND: ClassVar[str] = "message"
    seq: int = field(metadata=_rng(0, 2**63 - 1))
    t_ns: int = field(metadata=_rng(0, 2**63 - 1))


# --- vision -----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class HandPose(Message):
    """One camera frame's hand: landmarks and their mean, in normalised image coordinates."""

    KIND: ClassVar[str] = "hand"
    detected: bool = False
    center: Vec2 | None = field(default=None, metadata=_rng(-0.5, 1.5))
    landmarks: tuple[Vec2, ...] = field(default=(), metadata=_rng(-0.5, 1.5))
    source: str = "camera"

    def __post_init__(self) -> None:
        if self.detected and (self.center is None or not self.landmarks):
            raise MessageError("hand: detected=true needs a center and at least one landmark")
        if not self.detected and (self.center is not None or self.landmarks):
            raise MessageError("hand: detected=false must carry no center and no landmarks")


@dataclass(frozen=True, slots=True)
class Layout(Message):
    """The buzzer boxes [x1, y1, x2, y2] and the commit line y, normalised coordinates."""

    KIND: ClassVar[str] = "layout"
    red: tuple[float, float, float, float] = field(default=(0, 0, 0, 0), metadata=_rng(0, 1))
    blue: tuple[float, float, float, float] = field(default=(0, 0, 0, 0), metadata=_rng(0, 1))
    commit_y: float = field(default=0.45, metadata=_rng(0, 1))


# --- decision ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Scalar(Message):
    """One opinion-dynamics quantity (ẑ_h, z_r or b_r) computed from hand pose `src_seq`."""

    KIND: ClassVar[str] = "scalar"
    value: float = field(default=0.0, metadata=_rng(-1e6, 1e6))
    src_seq: int = field(default=0, metadata=_rng(0, 2**63 - 1))


# --- actuation --------------------------------------------------------------------------------

ArmAction = Literal["idle", "stop", "move", "press"]


@dataclass(frozen=True, slots=True)
class ArmCommandMsg(Message):
    """What actuation asked the arm to do (after Algorithm 2 and the safety gate)."""

    KIND: ClassVar[str] = "arm_cmd"
    action: ArmAction = "idle"
    direction: int = field(default=0, metadata=_rng(-1, 1))
    target: Literal["red", "blue"] | None = None
    reason: str = ""


@dataclass(frozen=True, slots=True)
class ArmStateMsg(Message):
    """The arm's state: end effector in table coordinates, phase, safety and faults."""

    KIND: ClassVar[str] = "arm_state"
    ee: Vec2 = field(default=(0.5, 0.1), metadata=_rng(-1, 2))
    phase: str = "idle"
    moving: bool = False
    target: Literal["red", "blue"] | None = None
    safe_stop: bool = False
    safety_reason: str = ""
    fault: str = ""


@dataclass(frozen=True, slots=True)
class PressMsg(Message):
    """A buzzer press, by the robot (actuation/press) or the human (experiment sees it)."""

    KIND: ClassVar[str] = "press"
    colour: Literal["red", "blue"] = "red"
    trial: int = field(default=0, metadata=_rng(0, 10_000))


# --- eyes -------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class GazeMsg(Message):
    """A gaze command: yaw ψ, pitch φ in radians, positive yaw toward red (SPEC §5)."""

    KIND: ClassVar[str] = "gaze"
    yaw: float = field(default=0.0, metadata=_rng(-math.pi, math.pi))
    pitch: float = field(default=0.0, metadata=_rng(-math.pi, math.pi))
    level: str = "neutral"
    gesture: bool = False
    trial: int = field(default=0, metadata=_rng(0, 10_000))


@dataclass(frozen=True, slots=True)
class EyesStateMsg(Message):
    """Servo targets actually sent (deg, µs), clamping report and safety state."""

    KIND: ClassVar[str] = "eyes_state"
    angles_deg: tuple[float, float, float, float] = field(
        default=(90, 90, 90, 90), metadata=_rng(-360, 360)
    )
    pulses_us: tuple[float, float, float, float] = field(
        default=(1500, 1500, 1500, 1500), metadata=_rng(0, 5000)
    )
    clamped: tuple[str, ...] = ()
    safe_stop: bool = False
    safety_reason: str = ""
    fault: str = ""


# --- experiment -------------------------------------------------------------------------------

TrialPhase = Literal["setup", "countdown", "go", "end", "result", "abort", "session_end"]


@dataclass(frozen=True, slots=True)
class TrialEvent(Message):
    """A step of the protocol: setup (mode, O, gaze), countdown, go, end, result, abort."""

    KIND: ClassVar[str] = "trial"
    phase: TrialPhase = "setup"
    trial: int = field(default=0, metadata=_rng(0, 10_000))
    mode: Literal["dissensus", "consensus"] = "dissensus"
    option: Literal["red", "blue"] | None = None
    text: str = ""
    session: str = ""


@dataclass(frozen=True, slots=True)
class TrialResult(Message):
    """The classified outcome of one trial."""

    KIND: ClassVar[str] = "result"
    trial: int = field(default=0, metadata=_rng(0, 10_000))
    mode: Literal["dissensus", "consensus"] = "dissensus"
    option: Literal["red", "blue"] | None = None
    robot: Literal["red", "blue"] | None = None
    human: Literal["red", "blue"] | None = None
    outcome: Literal["C", "CH", "D", "DH"] | None = None
    switches: int = field(default=0, metadata=_rng(0, 10_000))
    violations: int = field(default=0, metadata=_rng(0, 10_000))
    score: int = field(default=0, metadata=_rng(-100, 100))
    session: str = ""


# --- safety -----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Estop(Message):
    """Emergency stop: engaged=true latches a safe stop until a release (engaged=false)."""

    KIND: ClassVar[str] = "estop"
    engaged: bool = True
    reason: str = ""
    source: str = ""


# --- codec ------------------------------------------------------------------------------------


def encode(msg: Message) -> bytes:
    """Serialise a message to its msgpack map (tuples become arrays)."""
    data: dict[str, Any] = {"v": SCHEMA_VERSION}
    for f in dataclasses.fields(msg):
        data[f.name] = getattr(msg, f.name)
    return msgpack.packb(data, use_bin_type=True)


def decode(cls: type[M], payload: bytes) -> M:
    """Parse and validate a payload as message type `cls`, or raise MessageError."""
    name = cls.KIND
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise MessageError(f"{name}: payload of {len(payload)} bytes exceeds the limit")
    try:
        data = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types for garbage input
        raise MessageError(f"{name}: not valid msgpack ({type(exc).__name__})") from None
    if not isinstance(data, dict):
        raise MessageError(f"{name}: expected a map, got {type(data).__name__}")
    version = data.pop("v", None)
    if version != SCHEMA_VERSION:
        raise MessageError(f"{name}: schema version {version!r}, expected {SCHEMA_VERSION}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(str(k) for k in data if k not in fields)
    if unknown:
        raise MessageError(f"{name}: unknown field(s) {unknown}")
    hints = _hints(cls)
    kwargs: dict[str, Any] = {}
    for fname, f in fields.items():
        if fname not in data:
            if f.default is dataclasses.MISSING:
                raise MessageError(f"{name}: missing field '{fname}'")
            continue
        rng = f.metadata.get("range")
        kwargs[fname] = _check(hints[fname], data[fname], f"{name}.{fname}", rng)
    try:
        return cls(**kwargs)
    except MessageError:
        raise
    except (TypeError, ValueError) as exc:
        raise MessageError(f"{name}: {exc}") from None


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _check(tp: Any, value: Any, where: str, rng: tuple[float, float] | None) -> Any:
    """Validate one value against a type hint; return it normalised (lists → tuples)."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _check(inner[0], value, where, rng)
    if origin is Literal:
        if value not in args:
            raise MessageError(f"{where}: expected one of {list(args)}, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise MessageError(f"{where}: expected an array, got {type(value).__name__}")
        if len(args) == 2 and args[1] is Ellipsis:
            if len(value) > MAX_LANDMARKS:
                raise MessageError(f"{where}: {len(value)} items exceed {MAX_LANDMARKS}")
            return tuple(_check(args[0], v, f"{where}[{i}]", rng) for i, v in enumerate(value))
        if len(value) != len(args):
            raise MessageError(f"{where}: expected {len(args)} items, got {len(value)}")
        return tuple(
            _check(a, v, f"{where}[{i}]", rng)
            for i, (a, v) in enumerate(zip(args, value, strict=True))
        )
    if tp is bool:
        if not isinstance(value, bool):
            raise MessageError(f"{where}: expected true/false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise MessageError(f"{where}: expected an integer, got {value!r}")
        return _in_range(value, where, rng)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise MessageError(f"{where}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise MessageError(f"{where}: must be finite, got {value!r}")
        return _in_range(float(value), where, rng)
    if tp is str:
        if not isinstance(value, str):
            raise MessageError(f"{where}: expected a string, got {type(value).__name__}")
        if len(value) > 512:
            raise MessageError(f"{where}: string longer than 512 characters")
        return value
    raise MessageError(f"{where}: unsupported field type {tp!r}")  # a bug in this module


def _in_range(value: float, where: str, rng: tuple[float, float] | None) -> Any:
    if rng is not None and not rng[0] <= value <= rng[1]:
        raise MessageError(f"{where}: {value!r} outside [{rng[0]}, {rng[1]}]")
    return value
