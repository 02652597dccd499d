"""The one declaration of the rig's contract: every topic, its message, who talks, how often, QoS.

`TOPICS` is what the code runs on: `Node.publisher` takes each topic's QoS from here and refuses
a service that is not a declared publisher, `Node.subscribe` refuses one that is not a declared
subscriber, decoders take the message type from here, and the contract table of
docs/reference.md is `markdown_table()` (a test holds them equal; `python -m
services.core.contract` prints it, `--update docs/reference.md` rewrites it in place).
Services that read every key of a rig (`nod monitor`) subscribe to `nod/<rig>/**` and are not
listed per topic.

Each topic is also a constant named after its key, typed by its message: `DECISION_Z_R` is
`Topic[m.Opinions]`, so code that passes the constant instead of the name ("decision/z_r") has
the message class checked, and the topic's publishers and subscribers are one lookup away.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any, Generic, Literal, TypeAlias, TypeVar, overload

from services.core import messages as m

Congestion: TypeAlias = Literal["block", "drop"]
Priority: TypeAlias = Literal["real_time", "interactive_high", "data_high", "data"]


@dataclass(frozen=True, slots=True)
class QoS:
    """How a topic's samples travel (zenoh publisher options)."""

    # "block": never dropped (protocol events, presses, gaze, e-stop); "drop": the newest sample
    # matters more than an old one, so a congested link drops (camera-rate streams).
    congestion: Congestion
    priority: Priority = "data"
    express: bool = True  # sent at once, never batched: latency over throughput

    def describe(self) -> str:
        """One short cell of the contract table."""
        text = "reliable" if self.congestion == "block" else "drop if late"
        return text if self.priority == "data" else f"{text}, {self.priority.replace('_', '-')}"


STREAM = QoS("drop")
RELIABLE = QoS("block")
CONTROL = QoS("block", "interactive_high")
SAFETY = QoS("block", "real_time")


M = TypeVar("M", bound=m.Message, covariant=True)  # a topic's message class


@dataclass(frozen=True, slots=True)
class Topic(Generic[M]):
    """One key of the rig (`nod/<rig>/<name>`), carrying messages of class `M`."""

    name: str
    message: type[M]
    publishers: tuple[str, ...]
    subscribers: tuple[str, ...]
    rate: str
    qos: QoS
    fields: str  # the payload's own fields (besides v, seq, t_ns), for the reference table
    # Nothing is published on it: its publishers answer queries (`Node.answer`), so it is never
    # in a recording and never "silent".
    queried_only: bool = False

    def field_names(self) -> tuple[str, ...]:
        """The message's own field names, in order."""
        return tuple(f for f in m.fields(self.message) if f not in BASE)


BASE = ("seq", "t_ns")
# Every long-running process of a rig sends a heartbeat on rig/status.
EVERY_SERVICE = ("decision", "actuation", "eyes", "vision", "sim", "speaker", "display", "lsl",
                 "experiment", "monitor", "launcher", "estimate")

VISION_HAND = Topic(
    "vision/hand", m.HandPose, ("vision", "sim"),
    ("decision", "actuation", "experiment", "lsl", "estimate"),
    "camera (30 Hz)", STREAM,
    "`detected` bool, `center` [x,y] (mean of the landmarks) or nil, `landmarks` up to 64 "
    "[x,y] (21 from a hand model), normalised image coords, `source`",
)
VISION_LAYOUT = Topic(
    "vision/layout", m.Layout, ("vision", "sim"), ("decision", "actuation", "experiment"),
    "1 Hz + queryable", RELIABLE,
    "`options` (the option set's names), `boxes` [x1,y1,x2,y2] one per option (vision: found "
    "by colour), `commit_y`",
)
VISION_FRAME = Topic(
    "vision/frame", m.VisionFrame, ("vision",), (), "2 Hz", STREAM,
    "`jpeg` (downscaled, landmarks and boxes drawn), `width`, `height`, `hand_seq`, "
    "`detected`",
)
SIM_CAMERA = Topic(
    "sim/camera", m.VisionFrame, ("sim",), ("vision",), "30 Hz (`nod sim --render`)", STREAM,
    "a rendered camera frame: `jpeg`, `width`, `height`, `hand_seq`, `detected`",
)
DECISION_Z_H = Topic(
    "decision/z_h", m.Observed, ("decision",), ("experiment", "lsl"), "per pose", STREAM,
    "`options`, `values` ẑ_h one per option (two options: (ẑ_h, −ẑ_h)), `src_seq` (the pose's "
    "seq), `theta` θ and `distance` d of eq 7 when this pose set ẑ_h (else nil)",
)
DECISION_Z_R = Topic(
    "decision/z_r", m.Opinions, ("decision",), ("actuation", "experiment", "lsl"), "per pose",
    STREAM,
    "`options`, `values` z_r one per option, `src_seq`",
)
DECISION_B_R = Topic(
    "decision/b_r", m.Opinions, ("decision",), ("experiment", "lsl"), "per pose", STREAM,
    "`options`, `values` b_r one per option, `src_seq`",
)
ACTUATION_CMD = Topic(
    "actuation/cmd", m.ArmCommandMsg, ("actuation",), (), "on change", RELIABLE,
    "`action` idle/stop/move/press, `direction` ±1/0 (two options), `target` (an option), "
    "`reason`",
)
ACTUATION_STATE = Topic(
    "actuation/state", m.ArmStateMsg, ("actuation",), ("sim", "experiment", "estop", "lsl"),
    "50 Hz",
    STREAM,
    "`ee` [x,y], `phase`, `moving`, `target` (an option), `safe_stop`, `safety_reason`, `fault`, "
    "`estop` (latched), `estop_id` (the last e-stop command obeyed), `trial`",
)
ACTUATION_PRESS = Topic(
    "actuation/press", m.PressMsg, ("actuation",), ("experiment", "sim"), "once per trial",
    CONTROL, "`option` (the box the robot pressed), `trial`",
)
EYES_CMD = Topic(
    "eyes/cmd", m.GazeMsg, ("experiment",), ("eyes", "sim", "estimate"),
    "per cue + 20 Hz keep-alive", CONTROL,
    "`yaw`, `pitch` (rad, + toward red), `level`, `gesture` (a pose of the attention gesture), "
    "`trial`",
)
EYES_STATE = Topic(
    "eyes/state", m.EyesStateMsg, ("eyes",), ("experiment", "estop", "lsl"), "50 Hz", STREAM,
    "`angles_deg` ×4, `pulses_us` ×4, `clamped`, `safe_stop`, `safety_reason`, `fault`, "
    "`estop`, `estop_id`",
)
EXPERIMENT_TRIAL = Topic(
    "experiment/trial", m.TrialEvent, ("experiment",),
    ("decision", "actuation", "sim", "speaker", "display", "lsl", "run", "launcher",
     "operator", "lab", "estimate"),
    "per event", CONTROL,
    "`options`, `phase` setup/countdown/go/end/interrupted/abort/session_end, `trial`, "
    "`mode`, `option` (O, by name), `text`, `session`",
)
EXPERIMENT_RESULT = Topic(
    "experiment/result", m.TrialResult, ("experiment",),
    ("display", "lsl", "run", "launcher", "estimate"),
    "per trial", RELIABLE,
    "`options`, `trial`, `mode`, `option`, `robot`, `human` (by name), `outcome`, "
    "`switches`, `violations`, `score`, `session`, `interrupted`",
)
EXPERIMENT_OPERATOR = Topic(
    "experiment/operator", m.OperatorCmd, ("operator",), ("experiment",), "on demand", CONTROL,
    "the operator's start gate: `action` start (the waiting trial), pause (hold the next "
    "one) or freeze (the robot policy keeps its last settings), `trial` (the trial a start is "
    "for; 0: whichever waits), `source` (user@host)",
)
EXPERIMENT_POLICY = Topic(
    "experiment/policy", m.PolicyMsg, ("experiment",),
    ("decision", "operator", "run", "launcher"),
    "per trial (before its setup, again at its go) and on a freeze", CONTROL,
    "the robot policy's settings for `trial` of `session`: `policy` (its name), `sha256` (its "
    "file's), `b_star`, `gaze_level` (toward O), `u_r`, `frozen` (the operator froze it)",
)
ESTIMATE_PERSON = Topic(
    "estimate/person", m.PersonEstimate, ("estimate",), ("experiment",),
    "per trial (after its result)", RELIABLE,
    "the participant's parameters from their trials 1..`trial` of `session` (`nod estimate`): "
    "`trials_seen`, `seconds` (its cost), `params` [{`name`, `estimate`, `low`, `high` (the "
    "90 % interval or a 0/1 parameter's set), `probability`}]",
)
SPEAKER_PLAYED = Topic(
    "speaker/played", m.CuePlayed, ("speaker",), ("experiment",), "per countdown word and go",
    RELIABLE,
    "the participant's audio cue as played: `trial`, `cue` (the word), `planned_ns` (the "
    "`experiment/trial` event's t_ns), `played_ns` (rig clock when the sound started)",
)
RIG_STATUS = Topic(
    "rig/status", m.NodeStatus, EVERY_SERVICE, ("status", "experiment", "lab"),
    "1 Hz per service (wall time)", RELIABLE,
    "`service`, `host`, `pid`, `version`, `started_ns`, `wall_ns` (host wall clock: clock "
    "offsets), `restarts`, `received`, `dropped`, `params_hash` (12 hex digits of its "
    "parameters' SHA-256, or nil: the conductor refuses a decision or actuation with another), "
    "`session`, `participant`, `trial` (the conductor's, for the lab view; else empty)",
)
RIG_EVENT = Topic(
    "rig/event", m.RigEvent, ("launcher",), ("experiment", "status"), "on change",
    RELIABLE,
    "`host`, `service`, `kind` started/exited/restarting/gave_up/stopped, `code` (exit "
    "code; negative: the signal), `restarts`, `text`",
)
SAFETY_ESTOP = Topic(
    "safety/estop", m.Estop, ("estop",), ("actuation", "eyes", "experiment", "lsl"), "on demand",
    SAFETY,
    "engage only (`engaged` true; false is refused here): `engaged`, `reason`, `source` "
    "(user@host), `id` (acknowledged on the state keys)",
)
SAFETY_RELEASE = Topic(
    "safety/release", m.Estop, ("estop",), ("actuation", "eyes", "experiment", "lsl"),
    "on demand",
    SAFETY,
    "release only (`engaged` false), a key of its own so an ACL can let every host engage "
    "and only the control station release: `engaged`, `reason`, `source`, `id`",
)
SAFETY_LATCH = Topic(
    "safety/latch", m.LatchMsg, ("actuation", "eyes"),
    ("actuation", "eyes", "experiment", "estop"),
    "queryable (asked at start; `nod estop --release`)", RELIABLE,
    "each device answers with its e-stop latch: `service`, `engaged`, `reason`, `source`, "
    "`id`, `seen` (recent command ids), `floor` (the highest issue order it obeyed: a release "
    "must be above it, so no earlier command can be replayed to lift it); a device that "
    "starts is engaged if any is",
    queried_only=True,
)
_TOPICS: tuple[Topic[m.Message], ...] = (
    VISION_HAND, VISION_LAYOUT, VISION_FRAME, SIM_CAMERA, DECISION_Z_H, DECISION_Z_R, DECISION_B_R,
    ACTUATION_CMD, ACTUATION_STATE, ACTUATION_PRESS, EYES_CMD, EYES_STATE, EXPERIMENT_TRIAL,
    EXPERIMENT_RESULT, EXPERIMENT_OPERATOR, EXPERIMENT_POLICY, ESTIMATE_PERSON, SPEAKER_PLAYED,
    RIG_STATUS, RIG_EVENT, SAFETY_ESTOP, SAFETY_RELEASE, SAFETY_LATCH,
)
TOPICS: dict[str, Topic[m.Message]] = {t.name: t for t in _TOPICS}


class ContractError(RuntimeError):
    """Code tried to publish or subscribe outside the declared contract (a bug, not input)."""


@overload
def topic(name: Topic[M]) -> Topic[M]: ...
@overload
def topic(name: str) -> Topic[m.Message]: ...
def topic(name: str | Topic[Any]) -> Topic[Any]:
    """A topic by name or by its constant (the declared one); the error lists the known names."""
    key = name.name if isinstance(name, Topic) else name
    found = TOPICS.get(key)
    if found is None or (isinstance(name, Topic) and found is not name):
        raise KeyError(f"unknown topic {key!r}; known: {sorted(TOPICS)}")
    return found


class RoleCheck:
    """`check_publisher` and `check_subscriber`: one check, the role a parameter.

    A class, not a function each, so that the check, its message and its typing (a `Topic[M]`
    in, the same `Topic[M]` out) are written once for both roles.
    """

    def __init__(self, role: Literal["publishers", "subscribers"], verb: str) -> None:
        self.role = role
        self.verb = verb

    @overload
    def __call__(self, name: Topic[M], service: str) -> Topic[M]: ...
    @overload
    def __call__(self, name: str, service: str) -> Topic[m.Message]: ...
    def __call__(self, name: str | Topic[Any], service: str) -> Topic[Any]:
        """The topic, if `service` is one of its declared publishers (or subscribers)."""
        t = topic(name)
        declared = t.publishers if self.role == "publishers" else t.subscribers
        if service not in declared:
            raise ContractError(
                f"{service} {self.verb} {t.name}, but the contract names only {declared}: "
                "declare it in services/core/contract.py"
            )
        return t


check_publisher = RoleCheck("publishers", "publishes")
check_subscriber = RoleCheck("subscribers", "subscribes to")


def markdown_table() -> str:
    """The contract table (docs/reference.md), generated from `TOPICS`."""

    def names(who: tuple[str, ...]) -> str:
        tools = {"estop": "`nod estop`", "run": "`nod run`", "operator": "`nod experiment next`",
                 "lab": "`nod lab status`"}
        return ", ".join(tools.get(w, w) for w in who) or "—"

    rows = [
        "| key (`nod/<rig>/…`) | publishers | subscribers | rate | QoS | fields |",
        "|---|---|---|---|---|---|",
    ]
    for t in _TOPICS:
        rows.append(
            f"| `{t.name}` | {names(t.publishers)} | {names(t.subscribers)} | {t.rate} "
            f"| {t.qos.describe()} | {t.fields} |"
        )
    return "\n".join(rows) + "\n"


def update_readme(path: str) -> None:
    """Replace the table between a file's contract markers (docs/reference.md) with today's."""
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    begin = text.index("<!-- contract:begin")
    start = text.index("\n", begin) + 1
    end = text.index("<!-- contract:end -->")
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(text[:start] + markdown_table() + text[end:])


if __name__ == "__main__":  # python -m services.core.contract [--update docs/reference.md]
    if sys.argv[1:2] == ["--update"]:
        update_readme(sys.argv[2])
    else:
        sys.stdout.write(markdown_table())
