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

One schema for any number of options (version 3). A message about options carries them: the
table (`Layout`) and the opinions (`Opinions`: ẑ_h, z_r, b_r) carry the option set and one box
or value per option, the protocol's events and results the set and O by name, the arm's state,
commands and presses the box by name. The paper's study is the two-option case: options
("red", "blue") and the paper's signed opinion z as the vector (z, -z) (docs/multi-option.md,
"option_vector"), so `Opinions.signed` gives it back exactly. A receiver checks a message's
options against its own (`check_options`, `index_in`): a service started for another option
set is refused in one line.

Earlier schemas: version 1 (the paper's keys: scalars and colours) is read by
`services.core.schema1` (recordings made before this schema replay and convert); version 2 (the
retired `options/*` keys) is refused.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, ClassVar, Literal, TypeAlias, TypeVar

import msgspec
import numpy as np

from services.model.gaze import GazeLevelName
from services.model.geometry import COLOURS, Box, CommitLine, OptionsLayout, TableLayout
from services.model.schedule import MAX_OPTIONS

SCHEMA_VERSION = 3  # 1: the paper's two options (scalars, colours); 2: `options/*`; 3: one schema
MAX_PAYLOAD_BYTES = 64 * 1024  # no message of ours comes near this; larger is garbage
MAX_LANDMARKS = 64
MAX_BLOB_BYTES = 256 * 1024  # a `bytes` field (the monitor's JPEG frame); larger is garbage
MAX_TEXT = 512


def schema_version(cls: type[Any]) -> int:
    """The schema version a message class is written in: its `v` tag."""
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
# an option's name (the paper's: red, blue), and an option set: its names in box order
OptionName: TypeAlias = Annotated[str, msgspec.Meta(min_length=1, max_length=32)]
OptionSet: TypeAlias = Annotated[
    tuple[OptionName, ...], msgspec.Meta(min_length=2, max_length=MAX_OPTIONS)
]
# normalised image coordinates, with a margin for off-frame hands
Coord: TypeAlias = Annotated[float, msgspec.Meta(ge=-0.5, le=1.5)]
Vec2: TypeAlias = tuple[Coord, Coord]
Unit: TypeAlias = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
Pixels: TypeAlias = Annotated[int, msgspec.Meta(ge=1, le=8192)]
Score: TypeAlias = Annotated[int, msgspec.Meta(ge=-100, le=100)]
Direction: TypeAlias = Annotated[int, msgspec.Meta(ge=-1, le=1)]
# ẑ_h, z_r, b_r: finite, far beyond any value the model reaches
Opinion: TypeAlias = Annotated[float, msgspec.Meta(ge=-1e6, le=1e6)]
Vector: TypeAlias = Annotated[
    tuple[Opinion, ...], msgspec.Meta(min_length=2, max_length=MAX_OPTIONS)
]
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
    """The table: the option set, one box [x1, y1, x2, y2] per option, the commit line y."""

    KIND: ClassVar[str] = "layout"
    options: OptionSet
    boxes: Annotated[tuple[Box4, ...], msgspec.Meta(min_length=2, max_length=MAX_OPTIONS)]
    commit_y: Unit = 0.45

    def __post_init__(self) -> None:
        _distinct(self.KIND, self.options)
        if len(self.options) != len(self.boxes):
            raise MessageError(
                f"layout: {len(self.options)} options but {len(self.boxes)} boxes"
            )
        for name, (x1, y1, x2, y2) in zip(self.options, self.boxes, strict=True):
            if x1 > x2 or y1 > y2:
                raise MessageError(f"layout: the {name} box needs x1 <= x2 and y1 <= y2")

    def table(self) -> OptionsLayout:
        """The geometry it carries (box j is option j's)."""
        return OptionsLayout(tuple(Box(*b) for b in self.boxes), CommitLine(y=self.commit_y))

    def paper_table(self) -> TableLayout:
        """The two-option table as the paper's kernel reads it: option 0 red, option 1 blue."""
        if len(self.boxes) != 2:
            raise MessageError(f"layout: {len(self.boxes)} boxes, not the paper's two")
        red, blue = (Box(*b) for b in self.boxes)
        return TableLayout(red=red, blue=blue, commit=CommitLine(y=self.commit_y))


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


def layout_fields(
    options: tuple[str, ...], layout: OptionsLayout | TableLayout
) -> dict[str, Any]:
    """The fields of a `vision/layout` message for a geometry and its option names."""
    table = OptionsLayout.from_table(layout) if isinstance(layout, TableLayout) else layout
    if len(table.boxes) != len(options):
        raise ValueError(f"{len(options)} option names for {len(table.boxes)} boxes")
    return {
        "options": tuple(options),
        "boxes": tuple((b.x1, b.y1, b.x2, b.y2) for b in table.boxes),
        "commit_y": table.commit.y,
    }


# --- decision ---------------------------------------------------------------------------------


class Opinions(Message, frozen=True, kw_only=True):
    """One opinion-dynamics quantity (ẑ_h, z_r or b_r) over the options, from pose `src_seq`.

    `values[j]` is option j's; they sum to zero (the model's subspace). With the paper's two
    options the vector is (z, -z) for the paper's signed z: `signed` is z, exactly.
    """

    KIND: ClassVar[str] = "opinions"
    options: OptionSet
    values: Vector
    src_seq: Counter = 0

    def __post_init__(self) -> None:
        if len(self.values) != len(self.options):
            raise MessageError(
                f"{self.KIND}: {len(self.values)} values for {len(self.options)} options"
            )

    @property
    def signed(self) -> float:
        """The paper's signed opinion of a two-option message (z > 0: option 0, red)."""
        if len(self.values) != 2:
            raise MessageError(f"{self.KIND}: {len(self.values)} options have no signed opinion")
        return self.values[0]

    def vector(self, options: tuple[str, ...]) -> np.ndarray:
        """The values as an array, refused (one line) when they are not over `options`."""
        check_options(self, options)
        return np.array(self.values, dtype=float)


class Observed(Opinions, frozen=True, kw_only=True):
    """ẑ_h with what it was read from: θ (rad) and d (normalised) when this pose set it."""

    KIND: ClassVar[str] = "observed"
    theta: Annotated[float, msgspec.Meta(ge=0.0, le=math.pi)] | None = None
    distance: Annotated[float, msgspec.Meta(ge=0.0, le=5.0)] | None = None


def signed_fields(z: float, options: tuple[str, ...] = COLOURS) -> dict[str, Any]:
    """The `options` and `values` of an `Opinions` message for the paper's signed opinion z."""
    if len(options) != 2:
        raise ValueError(f"a signed opinion is over two options, not {len(options)}")
    return {"options": tuple(options), "values": (z, -z)}


# --- actuation --------------------------------------------------------------------------------

ArmAction = Literal["idle", "stop", "move", "press"]


class ArmCommandMsg(Message, frozen=True, kw_only=True):
    """What actuation asked the arm to do (after Algorithm 2 and the safety gate)."""

    KIND: ClassVar[str] = "arm_cmd"
    action: ArmAction = "idle"
    direction: Direction = 0  # two options: toward option 0 (+1) or 1 (-1); else 0
    target: OptionName | None = None
    reason: Text = ""


class ArmStateMsg(Message, frozen=True, kw_only=True):
    """The arm's state: end effector in table coordinates, phase, safety and faults."""

    KIND: ClassVar[str] = "arm_state"
    ee: tuple[Table, Table] = (0.5, 0.1)
    phase: Text = "idle"
    moving: bool = False
    target: OptionName | None = None  # the box it heads for or presses, by option name
    safe_stop: bool = False
    safety_reason: Text = ""
    fault: Text = ""
    estop: bool = False  # the e-stop is engaged (latched)
    estop_id: Text = ""  # the last e-stop command obeyed (engage or release): the acknowledgement
    trial: Trial = 0  # the trial the arm is in (from the conductor's setup)


class PressMsg(Message, frozen=True, kw_only=True):
    """A buzzer press, by the robot (actuation/press) or the human (experiment sees it)."""

    KIND: ClassVar[str] = "press"
    option: OptionName
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
    options: OptionSet
    phase: TrialPhase = "setup"
    trial: Trial = 0
    mode: Mode = "dissensus"
    option: OptionName | None = None
    text: Text = ""
    session: Text = ""

    def __post_init__(self) -> None:
        _named(self, option=self.option)


class TrialResult(Message, frozen=True, kw_only=True):
    """The classified outcome of one trial."""

    KIND: ClassVar[str] = "result"
    options: OptionSet
    trial: Trial = 0
    mode: Mode = "dissensus"
    option: OptionName | None = None
    robot: OptionName | None = None
    human: OptionName | None = None
    outcome: Literal["C", "CH", "D", "DH"] | None = None
    switches: Trial = 0
    violations: Trial = 0
    score: Score = 0
    session: Text = ""
    interrupted: bool = False  # broken by a safe stop or e-stop and not repeated: not scored

    def __post_init__(self) -> None:
        _named(self, option=self.option, robot=self.robot, human=self.human)


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
    # freeze: the robot policy keeps its last settings for the rest of the session
    action: Literal["start", "pause", "freeze"] = "start"
    trial: Trial = 0  # the trial a start is for (0: whichever waits)
    source: Text = ""  # user@host


# --- the robot policy and the person's estimate (issue 36) -------------------------------------

Setting: TypeAlias = Annotated[float, msgspec.Meta(gt=0.0, le=100.0)]  # b*, u_r
Sha256: TypeAlias = Annotated[str, msgspec.Meta(pattern=r"^([0-9a-f]{64})?$", max_length=64)]
Estimate: TypeAlias = Annotated[float, msgspec.Meta(ge=-1e9, le=1e9)]


class PolicyMsg(Message, frozen=True, kw_only=True):
    """The robot policy's settings for one trial, sent before its setup and again at its "go".

    The decision engine runs the trial on its b* and u_r; the gaze level is the one the
    conductor commands (toward O, or neutral). `frozen`: the operator froze the policy, so
    these settings hold for the rest of the session.
    """

    KIND: ClassVar[str] = "policy"
    session: Text = ""
    trial: Trial = 0
    policy: Annotated[str, msgspec.Meta(min_length=1, max_length=64)] = "paper"
    sha256: Sha256 = ""  # the policy file's
    b_star: Setting = 4.54
    gaze_level: GazeLevelName = "neutral"
    u_r: Setting = 2.24
    frozen: bool = False


class ParamEstimate(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """One parameter of the person: its estimate and 90 % interval (a 0/1 one: its set)."""

    name: Annotated[str, msgspec.Meta(min_length=1, max_length=64)]
    estimate: Estimate
    low: Estimate
    high: Estimate
    probability: Unit | None = None  # a 0/1 parameter's probability of 1

    def __post_init__(self) -> None:
        if not self.low <= self.estimate <= self.high:
            raise ValueError(f"{self.name}: the estimate {self.estimate} lies outside its "
                             f"interval [{self.low}, {self.high}]")


class PersonEstimate(Message, frozen=True, kw_only=True):
    """The participant's parameters estimated from their trials 1..`trial` (`nod estimate`)."""

    KIND: ClassVar[str] = "estimate"
    session: Text = ""
    trial: Trial = 0  # the last trial it read
    trials_seen: Trial = 0  # of trials 1..trial, how many it heard (a restarted one: fewer)
    seconds: Annotated[float, msgspec.Meta(ge=0.0, le=3600.0)] = 0.0  # the estimate's own time
    params: Annotated[tuple[ParamEstimate, ...], msgspec.Meta(max_length=64)] = ()


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


# --- options: every receiver checks a message's options against its own -----------------------


def _distinct(kind: str, options: tuple[str, ...]) -> None:
    if len(set(options)) != len(options):
        raise MessageError(f"{kind}: options must be distinct names, got {list(options)}")


def _named(msg: TrialEvent | TrialResult, **names: str | None) -> None:
    """The message's options are distinct and every option it names is one of them."""
    _distinct(msg.KIND, msg.options)
    for field, name in names.items():
        if name is not None and name not in msg.options:
            raise MessageError(
                f"{msg.KIND}: {field} {name!r} is none of its options {list(msg.options)}"
            )


def check_options(msg: Layout | Opinions | TrialEvent | TrialResult,
                  options: tuple[str, ...]) -> None:
    """Refuse (MessageError, one line) a message about another option set than ours."""
    if tuple(msg.options) != tuple(options):
        raise MessageError(
            f"{msg.KIND}: for options {','.join(msg.options)} but this rig runs "
            f"{','.join(options)}; start every service with the same --options (or params file)"
        )


def index_in(options: tuple[str, ...], name: str, kind: str = "message") -> int:
    """The box index of an option name (MessageError, one line, if it is none of ours)."""
    try:
        return options.index(name)
    except ValueError:
        raise MessageError(
            f"{kind}: option {name!r} is none of this rig's {','.join(options)}; start every "
            "service with the same --options (or params file)"
        ) from None


# --- codec ------------------------------------------------------------------------------------

class _NoVersion(Message, frozen=True, kw_only=True, tag=-1):
    """A type never sent, only decoded against: it makes the schema version `v` required.

    msgspec accepts a map without its tag when decoding one tagged type alone; decoding
    `cls | _NoVersion` needs the tag to choose, and a message without `v` is garbage.
    """


M = TypeVar("M", bound=Message)
_ENCODER = msgspec.msgpack.Encoder()
_JSON_ENCODER = msgspec.json.Encoder()
_DECODERS: dict[type[Message], msgspec.msgpack.Decoder[Any]] = {}
_JSON_DECODERS: dict[type[Message], msgspec.json.Decoder[Any]] = {}
JSON_SIZE_FACTOR = 2  # a JSON payload's limit, × the msgpack one (base64 bytes, field names)


def fields(cls: type[Message]) -> tuple[str, ...]:
    """The field names of a message type, in order (`seq` and `t_ns` first)."""
    return tuple(cls.__struct_fields__)


def encode(msg: Message) -> bytes:
    """Serialise a message to its msgpack map (with `v`; tuples become arrays)."""
    return _ENCODER.encode(msg)


def encode_json(msg: Message) -> bytes:
    """The message as a JSON object, as recordings keep it (`bytes` fields as base64 strings)."""
    return _JSON_ENCODER.encode(msg)


def decode(cls: type[M], payload: bytes) -> M:
    """Parse and validate a payload as message type `cls`, or raise MessageError."""
    decoder = _DECODERS.get(cls)
    if decoder is None:
        decoder = _DECODERS[cls] = msgspec.msgpack.Decoder(cls | _NoVersion)
    return _checked(cls, decoder, payload, cls.MAX_BYTES, "msgpack")


def decode_json(cls: type[M], data: bytes) -> M:
    """Parse and validate a JSON object (`encode_json`'s) as message type `cls`, or MessageError.

    The same checks as `decode`: a recorded JSON message is held to the contract as a payload.
    """
    decoder = _JSON_DECODERS.get(cls)
    if decoder is None:
        decoder = _JSON_DECODERS[cls] = msgspec.json.Decoder(cls | _NoVersion)
    return _checked(cls, decoder, data, cls.MAX_BYTES * JSON_SIZE_FACTOR, "JSON")


def _checked(cls: type[M], decoder: msgspec.msgpack.Decoder[Any] | msgspec.json.Decoder[Any],
             payload: bytes, limit: int, syntax: str) -> M:
    name = cls.KIND
    if len(payload) > limit:
        raise MessageError(f"{name}: payload of {len(payload)} bytes exceeds the limit")
    try:
        msg = decoder.decode(payload)
    except msgspec.ValidationError as exc:
        text = str(exc)
        if "`$.v`" in text or "field `v`" in text:
            text = f"schema version is not {schema_version(cls)} ({text})"
        raise MessageError(f"{name}: {text}") from None
    except msgspec.DecodeError as exc:
        raise MessageError(f"{name}: not valid {syntax} ({exc})") from None
    if type(msg) is not cls:
        raise MessageError(f"{name}: schema version is not {schema_version(cls)}")
    return msg
