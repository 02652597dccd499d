"""The message contract: every payload on the wire, its msgpack codec and its strict validation.

A message is a frozen `msgspec.Struct`. On the wire it is a msgpack map holding the schema
version `v`, the sequence number `seq` and the source timestamp `t_ns` (ns, the publisher's
clock: wall clock in real time, the shared simulated clock under `--sim`), plus the message's
own fields.

`decode(cls, payload)` checks everything a peer could get wrong — size, msgpack syntax, schema
version, missing or unknown fields, types (a bool is not a number), ranges (every number has
one, so NaN and ±inf never pass), lengths, and each message's own cross-field rules — and raises
one `MessageError` whose text names the field, so a service can log one line and carry on.
The checks run in msgspec's compiled decoder: a 21-landmark hand pose decodes in ~1.5 µs.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, ClassVar, Literal, TypeAlias, TypedDict, TypeVar

import msgspec
import numpy as np

from services.model.geometry import Box, CommitLine, OptionsLayout, TableLayout
from services.model.schedule import MAX_OPTIONS

SCHEMA_VERSION = 1
MAX_PAYLOAD_BYTES = 64 * 1024  # no message of ours comes near this; larger is garbage
MAX_LANDMARKS = 64
MAX_BLOB_BYTES = 256 * 1024  # a `bytes` field (the monitor's JPEG frame); larger is garbage
MAX_TEXT = 512


def schema_version(cls: type[Any]) -> int:
    """The schema version a message class is written in: its `v` tag (1, or 2 on `options/*`)."""
    tag = cls.__struct_config__.tag
    assert isinstance(tag, int)
    return tag


class MessageError(ValueError):
    """A payload failed to decode or validate; the text says which field and why."""


# Every number has a range: `Annotated[float, msgspec.Meta(ge=lo, le=hi)]` is a float in [lo, hi]
# to the decoder (NaN fails every bound, so it is rejected too) and a plain float to a type checker.
Counter: TypeAlias = Annotated[int, msgspec.Meta(ge=0, le=2**63 - 1)]
Text: TypeAlias = Annotated[str, msgspec.Meta(max_length=MAX_TEXT)]
Trial: TypeAlias = Annotated[int, msgspec.Meta(ge=0, le=10_000)]
Colour: TypeAlias = Literal["red", "blue"]
# normalised image coordinates, with a margin for off-frame hands
Coord: TypeAlias = Annotated[float, msgspec.Meta(ge=-0.5, le=1.5)]
Vec2: TypeAlias = tuple[Coord, Coord]
Unit: TypeAlias = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
Pixels: TypeAlias = Annotated[int, msgspec.Meta(ge=1, le=8192)]
Score: TypeAlias = Annotated[int, msgspec.Meta(ge=-100, le=100)]
Direction: TypeAlias = Annotated[int, msgspec.Meta(ge=-1, le=1)]
# ẑ_h, z_r, b_r: finite, far beyond any value the model reaches
Opinion: TypeAlias = Annotated[float, msgspec.Meta(ge=-1e6, le=1e6)]
Radians: TypeAlias = Annotated[float, msgspec.Meta(ge=-math.pi, le=math.pi)]
# the arm's end effector, table coordinates with a margin
Table: TypeAlias = Annotated[float, msgspec.Meta(ge=-1, le=2)]
Box4: TypeAlias = tuple[Unit, Unit, Unit, Unit]
ServiceName = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_.-]{1,64}$")]
Pid: TypeAlias = Annotated[int, msgspec.Meta(ge=0, le=2**31 - 1)]
Restarts: TypeAlias = Annotated[int, msgspec.Meta(ge=0, le=1_000_000)]
# a process's exit code; negative: killed by that signal
ExitCode: TypeAlias = Annotated[int, msgspec.Meta(ge=-255, le=255)]
# a fingerprint of a service's parameters (`services.core.config.params_hash`), lower-case hex
ParamsHash: TypeAlias = Annotated[str, msgspec.Meta(pattern=r"^[0-9a-f]{12,64}$")]


class Message(
    msgspec.Struct,
    frozen=True,
    kw_only=True,
    forbid_unknown_fields=True,
    tag_field="v",
    tag=SCHEMA_VERSION,
):
    """Base of every message: sequence number and source timestamp (`v` is the schema tag)."""

    KIND: ClassVar[str] = "message"
    MAX_BYTES: ClassVar[int] = MAX_PAYLOAD_BYTES  # payload size limit checked before decoding
    seq: Counter
    t_ns: Counter


# --- vision -----------------------------------------------------------------------------------


class HandPose(Message, frozen=True, kw_only=True):
    """One camera frame's hand: landmarks and their mean, in normalised image coordinates."""

    KIND: ClassVar[str] = "hand"
    detected: bool = False
    center: Vec2 | None = None
    landmarks: Annotated[tuple[Vec2, ...], msgspec.Meta(max_length=MAX_LANDMARKS)] = ()
    source: Text = "camera"

    def __post_init__(self) -> None:
        if self.detected and (self.center is None or not self.landmarks):
            raise MessageError("hand: detected=true needs a center and at least one landmark")
        if not self.detected and (self.center is not None or self.landmarks):
            raise MessageError("hand: detected=false must carry no center and no landmarks")


class Layout(Message, frozen=True, kw_only=True):
    """The buzzer boxes [x1, y1, x2, y2] and the commit line y, normalised coordinates."""

    KIND: ClassVar[str] = "layout"
    red: Box4 = (0.0, 0.0, 0.0, 0.0)
    blue: Box4 = (0.0, 0.0, 0.0, 0.0)
    commit_y: Unit = 0.45

    def __post_init__(self) -> None:
        for name in ("red", "blue"):
            x1, y1, x2, y2 = getattr(self, name)
            if x1 > x2 or y1 > y2:
                raise MessageError(f"layout: {name} box needs x1 <= x2 and y1 <= y2")


class VisionFrame(Message, frozen=True, kw_only=True):
    """A small downscaled JPEG of the camera with landmarks and boxes drawn, for the monitor."""

    KIND: ClassVar[str] = "frame"
    MAX_BYTES: ClassVar[int] = MAX_BLOB_BYTES + 1024  # the JPEG plus the other fields
    jpeg: Annotated[bytes, msgspec.Meta(max_length=MAX_BLOB_BYTES)] = b""
    width: Pixels = 1
    height: Pixels = 1
    hand_seq: Counter = 0  # the hand pose drawn
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


class Scalar(Message, frozen=True, kw_only=True):
    """One opinion-dynamics quantity (ẑ_h, z_r or b_r) computed from hand pose `src_seq`."""

    KIND: ClassVar[str] = "scalar"
    value: Opinion = 0.0
    src_seq: Counter = 0


class Observed(Scalar, frozen=True, kw_only=True):
    """ẑ_h with what it was read from: θ (rad) and d (normalised) when this pose set it."""

    KIND: ClassVar[str] = "observed"
    theta: Annotated[float, msgspec.Meta(ge=0.0, le=math.pi)] | None = None
    distance: Annotated[float, msgspec.Meta(ge=0.0, le=5.0)] | None = None


# --- actuation --------------------------------------------------------------------------------

ArmAction = Literal["idle", "stop", "move", "press"]


class ArmCommandMsg(Message, frozen=True, kw_only=True):
    """What actuation asked the arm to do (after Algorithm 2 and the safety gate)."""

    KIND: ClassVar[str] = "arm_cmd"
    action: ArmAction = "idle"
    direction: Direction = 0
    target: Colour | None = None
    reason: Text = ""


class ArmStateMsg(Message, frozen=True, kw_only=True):
    """The arm's state: end effector in table coordinates, phase, safety and faults."""

    KIND: ClassVar[str] = "arm_state"
    ee: tuple[Table, Table] = (0.5, 0.1)
    phase: Text = "idle"
    moving: bool = False
    target: Colour | None = None
    safe_stop: bool = False
    safety_reason: Text = ""
    fault: Text = ""
    estop: bool = False  # the e-stop is engaged (latched)
    estop_id: Text = ""  # the last e-stop command obeyed (engage or release): the acknowledgement
    trial: Trial = 0  # the trial the arm is in (from the conductor's setup)


class PressMsg(Message, frozen=True, kw_only=True):
    """A buzzer press, by the robot (actuation/press) or the human (experiment sees it)."""

    KIND: ClassVar[str] = "press"
    colour: Colour = "red"
    trial: Trial = 0


# --- eyes -------------------------------------------------------------------------------------


class GazeMsg(Message, frozen=True, kw_only=True):
    """A gaze command: yaw ψ, pitch φ in radians, positive yaw toward red (SPEC §5)."""

    KIND: ClassVar[str] = "gaze"
    yaw: Radians = 0.0
    pitch: Radians = 0.0
    level: Text = "neutral"
    gesture: bool = False
    trial: Trial = 0


Angle: TypeAlias = Annotated[float, msgspec.Meta(ge=-360, le=360)]
Pulse: TypeAlias = Annotated[float, msgspec.Meta(ge=0, le=5000)]


class EyesStateMsg(Message, frozen=True, kw_only=True):
    """Servo targets actually sent (deg, µs), clamping report and safety state."""

    KIND: ClassVar[str] = "eyes_state"
    angles_deg: tuple[Angle, Angle, Angle, Angle] = (90.0, 90.0, 90.0, 90.0)
    pulses_us: tuple[Pulse, Pulse, Pulse, Pulse] = (1500.0, 1500.0, 1500.0, 1500.0)
    clamped: Annotated[tuple[Text, ...], msgspec.Meta(max_length=8)] = ()
    safe_stop: bool = False
    safety_reason: Text = ""
    fault: Text = ""
    estop: bool = False  # the e-stop is engaged (latched)
    estop_id: Text = ""  # the last e-stop command obeyed (engage or release): the acknowledgement


# --- experiment -------------------------------------------------------------------------------

TrialPhase = Literal[
    "setup", "countdown", "go", "end", "interrupted", "result", "abort", "session_end"
]
Mode = Literal["dissensus", "consensus"]


class TrialEvent(Message, frozen=True, kw_only=True):
    """A step of the protocol: setup (mode, O, gaze), countdown, go, end, result, abort."""

    KIND: ClassVar[str] = "trial"
    phase: TrialPhase = "setup"
    trial: Trial = 0
    mode: Mode = "dissensus"
    option: Colour | None = None
    text: Text = ""
    session: Text = ""


class TrialResult(Message, frozen=True, kw_only=True):
    """The classified outcome of one trial."""

    KIND: ClassVar[str] = "result"
    trial: Trial = 0
    mode: Mode = "dissensus"
    option: Colour | None = None
    robot: Colour | None = None
    human: Colour | None = None
    outcome: Literal["C", "CH", "D", "DH"] | None = None
    switches: Trial = 0
    violations: Trial = 0
    score: Score = 0
    session: Text = ""
    interrupted: bool = False  # broken by a safe stop or e-stop and not repeated: not scored


# --- speaker ----------------------------------------------------------------------------------


class CuePlayed(Message, frozen=True, kw_only=True):
    """A countdown word or go as the speaker actually played it (rig-clock ns)."""

    KIND: ClassVar[str] = "played"
    trial: Trial = 0
    cue: Annotated[str, msgspec.Meta(min_length=1, max_length=32)] = "go"  # the word said
    planned_ns: Counter = 0  # the cue's `experiment/trial` event's t_ns
    played_ns: Counter = 0  # when the driver started the sound


# --- safety -----------------------------------------------------------------------------------


class Estop(Message, frozen=True, kw_only=True):
    """Emergency stop: engaged=true latches a safe stop until a release (engaged=false)."""

    KIND: ClassVar[str] = "estop"
    engaged: bool = True
    reason: Text = ""
    source: Text = ""
    id: Text = ""  # the command's id, echoed as `estop_id` on the state keys of each device obeying


class OperatorCmd(Message, frozen=True, kw_only=True):
    """The operator's command to the conductor: start the waiting trial, or hold the next one."""

    KIND: ClassVar[str] = "operator"
    action: Literal["start", "pause"] = "start"
    trial: Trial = 0  # the trial a start is for (0: whichever waits)
    source: Text = ""  # user@host


class LatchMsg(Message, frozen=True, kw_only=True):
    """A device's e-stop latch, in reply to a query on safety/latch (a starting device asks).

    `floor` is the highest issue order of any command the device obeyed: no release at or below
    it lifts a latch again; `seen` holds the ids of its recent commands (`services.model.latch`).
    """

    KIND: ClassVar[str] = "latch"
    service: ServiceName = "actuation"
    engaged: bool = True
    reason: Text = ""
    source: Text = ""
    id: Text = ""
    seen: Annotated[tuple[Annotated[str, msgspec.Meta(max_length=64)], ...],
                    msgspec.Meta(max_length=64)] = ()
    floor: Counter = 0


# --- the rig: service status and the launchers' events ------------------------------------------


class NodeStatus(Message, frozen=True, kw_only=True):
    """A service's heartbeat (1 Hz of wall time): who, where, since when, and its clock.

    `wall_ns` is the host's wall clock when the heartbeat left, whatever the session's clock
    (`t_ns` is the session's, simulated under `--sim`): `nod status` compares it with its own to
    estimate each host's clock offset.
    """

    KIND: ClassVar[str] = "status"
    service: ServiceName = "decision"
    host: Text = ""
    pid: Pid = 0
    version: Text = ""
    started_ns: Counter = 0  # wall clock at start
    wall_ns: Counter = 0
    restarts: Restarts = 0  # how often the launcher restarted this service
    received: Counter = 0  # messages handled so far
    dropped: Counter = 0  # bad messages dropped so far
    params_hash: ParamsHash | None = None  # its effective parameters; None: it has none
    # What the conductor is running (empty for every other service): the lab view's source.
    session: Text = ""
    participant: Text = ""
    trial: Trial = 0


RigEventKind = Literal["started", "exited", "restarting", "gave_up", "stopped"]


class RigEvent(Message, frozen=True, kw_only=True):
    """A launcher's account of a service it supervises: started, died, restarted, given up."""

    KIND: ClassVar[str] = "rig_event"
    host: Text = ""
    service: ServiceName = "decision"
    kind: RigEventKind = "started"
    code: ExitCode | None = None  # exit code (negative: killed by that signal)
    restarts: Restarts = 0
    text: Text = ""


# --- codec ------------------------------------------------------------------------------------

class _NoVersion(Message, frozen=True, kw_only=True, tag=-1):
    """A type never sent, only decoded against: it makes the schema version `v` required.

    msgspec accepts a map without its tag when decoding one tagged type alone; decoding
    `cls | _NoVersion` needs the tag to choose, and a message without `v` is garbage.
    """


M = TypeVar("M", bound=Message)
_ENCODER = msgspec.msgpack.Encoder()
_DECODERS: dict[type[Message], msgspec.msgpack.Decoder[Any]] = {}


def fields(cls: type[Message]) -> tuple[str, ...]:
    """The field names of a message type, in order (`seq` and `t_ns` first)."""
    return tuple(cls.__struct_fields__)


def encode(msg: Message) -> bytes:
    """Serialise a message to its msgpack map (with `v`; tuples become arrays)."""
    return _ENCODER.encode(msg)


def decode(cls: type[M], payload: bytes) -> M:
    """Parse and validate a payload as message type `cls`, or raise MessageError."""
    name = cls.KIND
    if len(payload) > cls.MAX_BYTES:
        raise MessageError(f"{name}: payload of {len(payload)} bytes exceeds the limit")
    decoder = _DECODERS.get(cls)
    if decoder is None:
        decoder = _DECODERS[cls] = msgspec.msgpack.Decoder(cls | _NoVersion)
    try:
        msg = decoder.decode(payload)
    except msgspec.ValidationError as exc:
        text = str(exc)
        if "`$.v`" in text or "field `v`" in text:
            text = f"schema version is not {schema_version(cls)} ({text})"
        raise MessageError(f"{name}: {text}") from None
    except msgspec.DecodeError as exc:
        raise MessageError(f"{name}: not valid msgpack ({exc})") from None
    if type(msg) is not cls:
        raise MessageError(f"{name}: schema version is not {schema_version(cls)}")
    return msg


# --- Schema 2: a table of N options (`options/*`) ----------------------------------------------
#
# The N_o-option messages: vectors over the options, on topics of their own, schema version 2.
#
# A table of three or more boxes talks on `options/*` keys (`services.core.contract`) with these
# messages, which carry one value per option. They are schema version 2 (`v` = 2): a payload of
# version 1 — the paper's messages, or a service of before the option set — is refused with
# "schema version is not 2", and one of version 2 on a paper key with "… is not 1". The paper's
# two-option topics and messages are unchanged, byte for byte, so the study's recordings,
# replays and stores are too (docs/multi-option.md says why this is not one message type for
# both).
#
# Every vector's length is checked twice: against the message's own `n_options` when it has one
# (a message that disagrees with itself never decodes), and against the receiver's option count
# by `values_for` (a service started with another `--options` is refused with one line).
#
# One module holds both schema versions; the next step of the project puts the options into the
# paper's keys' messages (one key space), and each service's key-space seam is where it changes.

OPTIONS_SCHEMA_VERSION = 2
OptionCount: TypeAlias = Annotated[int, msgspec.Meta(ge=2, le=MAX_OPTIONS)]
OptionIndex: TypeAlias = Annotated[int, msgspec.Meta(ge=0, le=MAX_OPTIONS - 1)]
Vector: TypeAlias = Annotated[
    tuple[Opinion, ...], msgspec.Meta(min_length=2, max_length=MAX_OPTIONS)
]
OptionName: TypeAlias = Annotated[str, msgspec.Meta(min_length=1, max_length=32)]


class OptionsMessage(
    Message, frozen=True, kw_only=True, tag=OPTIONS_SCHEMA_VERSION
):
    """Base of the N_o-option messages: `v` = 2, `seq`, `t_ns`."""

    KIND: ClassVar[str] = "options"


class OptionVector(OptionsMessage, frozen=True, kw_only=True):
    """One quantity over the options (ẑ_h, z_r or b_r) computed from hand pose `src_seq`."""

    KIND: ClassVar[str] = "option_vector"
    values: Vector = (0.0, 0.0)
    src_seq: Counter = 0


def values_for(msg: OptionVector, n_options: int) -> np.ndarray:
    """The vector as an array, refused with one line when its length is not `n_options`."""
    if len(msg.values) != n_options:
        raise MessageError(
            f"{msg.KIND}: {len(msg.values)} values but this rig runs {n_options} options; "
            "start every service with the same --options (or params file)"
        )
    return np.array(msg.values, dtype=float)


def check_count(msg: _WithOptionCount, n_options: int) -> None:
    """Refuse (MessageError, one line) a message for another number of options than ours."""
    if msg.n_options != n_options:
        raise MessageError(
            f"{msg.KIND}: for {msg.n_options} options but this rig runs {n_options}; start "
            "every service with the same --options (or params file)"
        )


def same_count(layout: OptionsLayout, n_options: int) -> OptionsLayout:
    """The layout, refused (MessageError, one line) when it has another number of boxes."""
    if layout.n_options != n_options:
        raise MessageError(
            f"options_layout: {layout.n_options} boxes but this rig runs {n_options} options; "
            "start every service with the same --options (or params file)"
        )
    return layout


class OptionsLayoutMsg(OptionsMessage, frozen=True, kw_only=True):
    """The table: option names, one box [x1, y1, x2, y2] per option, the commit line y."""

    KIND: ClassVar[str] = "options_layout"
    names: Annotated[tuple[OptionName, ...], msgspec.Meta(min_length=2, max_length=MAX_OPTIONS)]
    boxes: Annotated[tuple[Box4, ...], msgspec.Meta(min_length=2, max_length=MAX_OPTIONS)]
    commit_y: Unit = 0.45

    def __post_init__(self) -> None:
        if len(self.names) != len(self.boxes):
            raise MessageError(
                f"options_layout: {len(self.names)} names but {len(self.boxes)} boxes"
            )
        for j, (x1, y1, x2, y2) in enumerate(self.boxes):
            if x1 > x2 or y1 > y2:
                raise MessageError(f"options_layout: box {j} needs x1 <= x2 and y1 <= y2")

    def layout(self) -> OptionsLayout:
        """The geometry it carries."""
        return OptionsLayout(tuple(Box(*b) for b in self.boxes), CommitLine(y=self.commit_y))


class LayoutFields(TypedDict):
    """The fields of an `options/layout` message."""

    names: tuple[str, ...]
    boxes: tuple[tuple[float, float, float, float], ...]
    commit_y: float


def layout_message_fields(names: tuple[str, ...], layout: OptionsLayout) -> LayoutFields:
    """The fields of an `options/layout` message for a geometry and its option names."""
    return {
        "names": names,
        "boxes": tuple((b.x1, b.y1, b.x2, b.y2) for b in layout.boxes),
        "commit_y": layout.commit.y,
    }


class _WithOptionCount(OptionsMessage, frozen=True, kw_only=True):
    """A message naming options by index, with the count they index into."""

    n_options: OptionCount = 3

    def _check(self, **options: int | None) -> None:
        for name, value in options.items():
            if value is not None and value >= self.n_options:
                raise MessageError(
                    f"{self.KIND}: {name} {value} is not one of the {self.n_options} options"
                )


class OptionsArmState(_WithOptionCount, frozen=True, kw_only=True):
    """The N_o-box arm's state: end effector, phase, the box it heads for, safety."""

    KIND: ClassVar[str] = "options_arm_state"
    ee: tuple[Table, Table] = (0.5, 0.1)
    phase: Text = "idle"
    moving: bool = False
    target: OptionIndex | None = None
    safe_stop: bool = False
    safety_reason: Text = ""
    trial: Trial = 0

    def __post_init__(self) -> None:
        self._check(target=self.target)


class OptionsPress(_WithOptionCount, frozen=True, kw_only=True):
    """The robot's press of box `option` in trial `trial`."""

    KIND: ClassVar[str] = "options_press"
    option: OptionIndex = 0
    trial: Trial = 0

    def __post_init__(self) -> None:
        self._check(option=self.option)


class OptionsTrialEvent(_WithOptionCount, frozen=True, kw_only=True):
    """A step of the protocol over N_o options (`messages.TrialEvent` with O an index)."""

    KIND: ClassVar[str] = "options_trial"
    phase: TrialPhase = "setup"
    trial: Trial = 0
    mode: Mode = "dissensus"
    option: OptionIndex | None = None
    text: Text = ""
    session: Text = ""

    def __post_init__(self) -> None:
        self._check(option=self.option)


class OptionsResult(_WithOptionCount, frozen=True, kw_only=True):
    """The classified outcome of one N_o-option trial (options as indices)."""

    KIND: ClassVar[str] = "options_result"
    trial: Trial = 0
    mode: Mode = "dissensus"
    option: OptionIndex | None = None
    robot: OptionIndex | None = None
    human: OptionIndex | None = None
    outcome: Literal["C", "CH", "D", "DH"] | None = None
    switches: Trial = 0
    violations: Trial = 0
    score: Score = 0
    session: Text = ""
    interrupted: bool = False  # broken by safe stops and not repeated: stored, never scored

    def __post_init__(self) -> None:
        self._check(option=self.option, robot=self.robot, human=self.human)
