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
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal, TypeVar

import msgpack

from services.model.geometry import Box, CommitLine, TableLayout

SCHEMA_VERSION = 1
MAX_PAYLOAD_BYTES = 64 * 1024  # no message of ours comes near this; larger is garbage
MAX_LANDMARKS = 64
MAX_BLOB_BYTES = 256 * 1024  # a `bytes` field (the monitor's JPEG frame); larger is garbage

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
    MAX_BYTES: ClassVar[int] = MAX_PAYLOAD_BYTES  # payload size limit checked before decoding
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


@dataclass(frozen=True, slots=True)
class VisionFrame(Message):
    """A small downscaled JPEG of the camera with landmarks and boxes drawn, for the monitor."""

    KIND: ClassVar[str] = "frame"
    MAX_BYTES: ClassVar[int] = MAX_BLOB_BYTES + 1024  # the JPEG plus the other fields
    jpeg: bytes = b""
    width: int = field(default=1, metadata=_rng(1, 8192))
    height: int = field(default=1, metadata=_rng(1, 8192))
    hand_seq: int = field(default=0, metadata=_rng(0, 2**63 - 1))  # the hand pose drawn
    detected: bool = False

    def __post_init__(self) -> None:
        if not self.jpeg.startswith(b"\xff\xd8\xff"):
            raise MessageError("frame: jpeg must hold a JPEG image (starting with FF D8 FF)")
        if len(self.jpeg) > MAX_BLOB_BYTES:
            raise MessageError(f"frame: jpeg of {len(self.jpeg)} bytes exceeds {MAX_BLOB_BYTES}")


def layout_from_msg(msg: Layout) -> TableLayout:
    """The table geometry carried by a `vision/layout` message."""
    return TableLayout(red=Box(*msg.red), blue=Box(*msg.blue), commit=CommitLine(y=msg.commit_y))


def layout_fields(layout: TableLayout) -> dict[str, Any]:
    """The fields of a `vision/layout` message for a geometry."""
    r, b = layout.red, layout.blue
    return {
        "red": (r.x1, r.y1, r.x2, r.y2),
        "blue": (b.x1, b.y1, b.x2, b.y2),
        "commit_y": layout.commit.y,
    }


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
    if len(payload) > cls.MAX_BYTES:
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
    unknown = sorted(str(k) for k in data if k not in _field_names(cls))
    if unknown:
        raise MessageError(f"{name}: unknown field(s) {unknown}")
    kwargs: dict[str, Any] = {}
    for fname, required, check in _validators(cls):
        if fname not in data:
            if required:
                raise MessageError(f"{name}: missing field '{fname}'")
            continue
        kwargs[fname] = check(data[fname], f"{name}.{fname}")
    try:
        return cls(**kwargs)
    except MessageError:
        raise
    except (TypeError, ValueError) as exc:
        raise MessageError(f"{name}: {exc}") from None


Check = Callable[[Any, str], Any]
_VALIDATORS: dict[type, tuple[tuple[str, bool, Check], ...]] = {}
_NAMES: dict[type, frozenset[str]] = {}


def _field_names(cls: type) -> frozenset[str]:
    if cls not in _NAMES:
        _NAMES[cls] = frozenset(f.name for f in dataclasses.fields(cls))
    return _NAMES[cls]


def _validators(cls: type) -> tuple[tuple[str, bool, Check], ...]:
    """Per field: name, whether required, and a validator compiled once from the type hints.

    Compiling keeps the hot path (a 120 Hz hand pose with 21 landmarks) free of typing
    introspection: decoding costs a few µs instead of ~100 µs.
    """
    if cls not in _VALIDATORS:
        hints = typing.get_type_hints(cls)
        _VALIDATORS[cls] = tuple(
            (
                f.name,
                f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING,
                _compile(hints[f.name], f.metadata.get("range")),
            )
            for f in dataclasses.fields(cls)
        )
    return _VALIDATORS[cls]


def _compile(tp: Any, rng: tuple[float, float] | None) -> Check:
    """A validator for one type hint: (value, where) → normalised value, or MessageError.

    `where` names the field in error messages only; it is never formatted on success.
    """
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = _compile(next(a for a in args if a is not type(None)), rng)
        nullable = type(None) in args

        def check_union(value: Any, where: str) -> Any:
            if value is None and nullable:
                return None
            return inner(value, where)

        return check_union
    if origin is Literal:

        def check_literal(value: Any, where: str) -> Any:
            if value not in args or isinstance(value, bool) != any(
                isinstance(a, bool) for a in args
            ):
                raise MessageError(f"{where}: expected one of {list(args)}, got {value!r}")
            return value

        return check_literal
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            elem = _compile(args[0], rng)
            if args[0] == tuple[float, float]:
                return _points_checker(elem, rng)

            def check_seq(value: Any, where: str) -> Any:
                if not isinstance(value, list | tuple):
                    raise MessageError(f"{where}: expected an array, got {type(value).__name__}")
                if len(value) > MAX_LANDMARKS:
                    raise MessageError(f"{where}: {len(value)} items exceed {MAX_LANDMARKS}")
                try:
                    return tuple([elem(v, where) for v in value])
                except MessageError:  # redo the failing item to name its index in the error
                    for i, v in enumerate(value):
                        elem(v, f"{where}[{i}]")
                    raise

            return check_seq
        n = len(args)
        if all(a is float for a in args):  # points and boxes: the hot path of a hand pose
            lo, hi = rng if rng is not None else (-math.inf, math.inf)

            def check_floats(value: Any, where: str) -> Any:
                if type(value) is list and len(value) == n:
                    for v in value:
                        t = type(v)
                        if (t is not float and t is not int) or not lo <= v <= hi:
                            break
                    else:
                        return tuple([float(v) for v in value])
                return _floats_error(value, where, n, lo, hi)

            return check_floats
        items = tuple(_compile(a, rng) for a in args)

        def check_tuple(value: Any, where: str) -> Any:
            if not isinstance(value, list | tuple):
                raise MessageError(f"{where}: expected an array, got {type(value).__name__}")
            if len(value) != n:
                raise MessageError(f"{where}: expected {n} items, got {len(value)}")
            return tuple([c(v, where) for c, v in zip(items, value, strict=True)])

        return check_tuple
    if tp is bool:

        def check_bool(value: Any, where: str) -> Any:
            if value is not True and value is not False:
                raise MessageError(f"{where}: expected true/false, got {value!r}")
            return value

        return check_bool
    if tp is int:

        def check_int(value: Any, where: str) -> Any:
            if type(value) is not int:  # bool is not an int here
                raise MessageError(f"{where}: expected an integer, got {value!r}")
            return _in_range(value, where, rng)

        return check_int
    if tp is float:
        lo, hi = rng if rng is not None else (-math.inf, math.inf)

        def check_float(value: Any, where: str) -> Any:
            t = type(value)
            if t is not float and t is not int:
                raise MessageError(f"{where}: expected a number, got {value!r}")
            if not lo <= value <= hi:  # NaN fails every comparison
                if not math.isfinite(value):
                    raise MessageError(f"{where}: must be finite, got {value!r}")
                raise MessageError(f"{where}: {value!r} outside [{lo}, {hi}]")
            if not math.isfinite(value):
                raise MessageError(f"{where}: must be finite, got {value!r}")
            return float(value)

        return check_float
    if tp is bytes:

        def check_bytes(value: Any, where: str) -> Any:
            if not isinstance(value, bytes):
                raise MessageError(f"{where}: expected binary data, got {type(value).__name__}")
            if len(value) > MAX_BLOB_BYTES:
                raise MessageError(f"{where}: {len(value)} bytes exceed {MAX_BLOB_BYTES}")
            return value

        return check_bytes
    if tp is str:

        def check_str(value: Any, where: str) -> Any:
            if not isinstance(value, str):
                raise MessageError(f"{where}: expected a string, got {type(value).__name__}")
            if len(value) > 512:
                raise MessageError(f"{where}: string longer than 512 characters")
            return value

        return check_str
    raise TypeError(f"unsupported message field type {tp!r}")  # a bug in this module


def _points_checker(elem: Check, rng: tuple[float, float] | None) -> Check:
    """Landmark arrays, the bulk of the hot path: one tight loop; details only on failure."""
    lo, hi = rng if rng is not None else (-math.inf, math.inf)

    def check_points(value: Any, where: str) -> Any:
        if type(value) is list and len(value) <= MAX_LANDMARKS:
            out = []
            for p in value:
                if type(p) is not list or len(p) != 2:
                    break
                x, y = p
                if type(x) is not float or type(y) is not float:
                    break
                if not (lo <= x <= hi and lo <= y <= hi):  # NaN fails too
                    break
                out.append((x, y))
            else:
                return tuple(out)
        if not isinstance(value, list | tuple):
            raise MessageError(f"{where}: expected an array, got {type(value).__name__}")
        if len(value) > MAX_LANDMARKS:
            raise MessageError(f"{where}: {len(value)} items exceed {MAX_LANDMARKS}")
        return tuple(elem(v, f"{where}[{i}]") for i, v in enumerate(value))

    return check_points


def _floats_error(value: Any, where: str, n: int, lo: float, hi: float) -> Any:
    """Say exactly what is wrong with an array of n numbers (the rare, slow path)."""
    if not isinstance(value, list | tuple):
        raise MessageError(f"{where}: expected an array, got {type(value).__name__}")
    if len(value) != n:
        raise MessageError(f"{where}: expected {n} items, got {len(value)}")
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise MessageError(f"{where}[{i}]: expected a number, got {v!r}")
        if not math.isfinite(v):
            raise MessageError(f"{where}[{i}]: must be finite, got {v!r}")
        if not lo <= v <= hi:
            raise MessageError(f"{where}[{i}]: {v!r} outside [{lo}, {hi}]")
    return tuple(float(v) for v in value)  # a tuple where a list was expected: fine


def _in_range(value: float, where: str, rng: tuple[float, float] | None) -> Any:
    if rng is not None and not rng[0] <= value <= rng[1]:
        raise MessageError(f"{where}: {value!r} outside [{rng[0]}, {rng[1]}]")
    return value
