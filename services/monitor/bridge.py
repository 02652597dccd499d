"""The Rerun bridge: one decoded message in, the Rerun log calls that show it out.

No Zenoh here: `RerunBridge.log(topic, msg)` takes a message of the contract and logs it to a
`rerun.RecordingStream`, so it is tested against a recording saved to an `.rrd` file. Every row is
stamped with the message's own source time `t_ns` on the `time` timeline and with the current
trial on the `trial` sequence timeline. The entity tree (`ENTITIES`) is
`services.views.entities`' (its module doc lists the tree; the recordings' blueprint lays it
out too; camera frames are all at FRAME_SIZE), and the views the monitor's blueprint shares with
it are `services.views.blueprint`'s.

One key space, schema 3, for any option set: every message names its options, so one table,
arm, trial and result line serves every N. Only the opinions are shown two ways: over the
paper's two options a message's signed value (`Opinions.signed`, z > 0 toward option 0) is a
time series as it always was; over three or more the vector is a bar chart, one bar per option.
Boxes are drawn in their options' colours and labelled by name, so the paper's red and blue are
the N-option case's red and blue.

Not shown: `sim/camera`, the rendered 30 Hz camera that `nod sim --render` feeds to `nod vision`
(full-size JPEGs at camera rate); the camera view shows vision's annotated `vision/frame` only.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from services.core import messages as m
from services.model.servos import SERVO_NAMES
from services.scene.option_colours import COLOURS
from services.views.blueprint import opinions_view, table_view
from services.views.entities import ENTITIES, TIMELINE, TRIAL_TIMELINE

# Keys the monitor does not record: the raw rendered camera is vision's input (30 Hz, full size);
# the camera view shows vision's own low-rate annotated frames (`vision/frame`).
NOT_SHOWN: frozenset[str] = frozenset({"sim/camera"})
FRAME_SIZE = (320, 240)  # (width, height) of every camera/frame image; others are letterboxed
FRAME_QUALITY = 80  # JPEG quality of a frame the bridge had to resize

# Where the robot is drawn on the table (normalised image coordinates, x right, y down). The
# robot sits across the table from the participant, at the middle of the image's top edge
# (services/model/arm_kinematics.py: the simulated arm's home (0.5, 0.08) is just in front of it).
ARM_BASE = (0.5, 0.0)  # where the arm is mounted: its segment runs from here to the end effector
EYES = ((0.45, 0.0), (0.55, 0.0))  # the two eyes, either side of the arm's base
GAZE_LENGTH = 0.25  # length of a gaze arrow (normalised)

RED = (220, 50, 47)
BLUE = (38, 110, 220)
GREY = (160, 160, 160)  # a box whose option's name is not a known colour
GAZE_COLOUR = (200, 120, 255)
SCALAR_STYLE: dict[str, tuple[str, tuple[int, int, int]]] = {
    "decision/z_h": ("ẑ_h (human, observed)", (230, 140, 20)),
    "decision/z_r": ("z_r (robot)", (20, 150, 90)),
    "decision/b_r": ("b_r (robot bias)", (130, 80, 200)),
}


def blueprint(bars: bool = False) -> rrb.Blueprint:
    """The at-a-glance layout: opinions and states left, table, camera and text log right.

    With `bars` the opinions are vectors over three or more options, one bar chart each (a time
    series of a vector over N options does not read at a glance); everything else is the same.
    """
    left = rrb.Vertical(
        opinions_view(bars),
        rrb.Horizontal(
            rrb.TimeSeriesView(origin="eyes/gaze", name="gaze command (rad)"),
            rrb.TimeSeriesView(origin="eyes/servos", name="eye servo targets (deg)"),
        ),
        rrb.StateTimelineView(origin="state", name="trial · arm · gaze"),
        row_shares=[3, 2, 1],
    )
    width, height = FRAME_SIZE
    right = rrb.Vertical(
        rrb.Horizontal(
            table_view(),
            rrb.Spatial2DView(
                origin="camera",
                name="camera",
                visual_bounds=rrb.VisualBounds2D(x_range=[0.0, width], y_range=[0.0, height]),
            ),
        ),
        rrb.TextLogView(origin="log", name="events, outcomes, safety"),
        row_shares=[3, 2],
    )
    return rrb.Blueprint(
        rrb.Horizontal(left, right, column_shares=[3, 2]),
        rrb.TimePanel(timeline=TIMELINE),
        collapse_panels=True,
    )


_NUMBERS = re.compile(r"\d+(\.\d+)?")


def _opt(value: str | None) -> str:
    return value if value else "-"


def box_colour(name: str) -> tuple[int, int, int]:
    """The RGB of option `name`'s box: the paper's red and blue, a known colour, else grey."""
    if name == "red":
        return RED
    if name == "blue":
        return BLUE
    if name in COLOURS:
        b, g, r = COLOURS[name][0]  # BGR paint of the rendered table
        return (r, g, b)
    return GREY


def gaze_arrows(yaw: float, length: float = GAZE_LENGTH) -> tuple[np.ndarray, np.ndarray]:
    """Origins and vectors of the gaze arrows on the table: from each eye, toward the yaw.

    The robot faces the participant (+y, down the image); yaw ψ turns the eyes toward red for
    ψ > 0, which is +x in the image (red's box is on the right), so the direction is (sin ψ, cos ψ).
    """
    vector = (length * np.sin(yaw), length * np.cos(yaw))
    return np.array(EYES, dtype=np.float32), np.array([vector] * len(EYES), dtype=np.float32)


def fit_frame(jpeg: bytes, size: tuple[int, int] = FRAME_SIZE) -> bytes | None:
    """The JPEG at exactly `size` (width, height), or None if it does not decode.

    A frame of that size is passed through untouched; another is scaled to fit (aspect kept),
    centred on black and encoded again, so the camera view never changes size.
    """
    img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        return None
    width, height = size
    h, w = img.shape[:2]
    if (w, h) == size:
        return jpeg
    scale = min(width / w, height / h)
    fw, fh = max(1, round(w * scale)), max(1, round(h * scale))
    interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
    out = np.zeros((height, width, 3), np.uint8)
    x0, y0 = (width - fw) // 2, (height - fh) // 2
    out[y0 : y0 + fh, x0 : x0 + fw] = cv2.resize(img, (fw, fh), interpolation=interp)
    ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, FRAME_QUALITY])
    return buf.tobytes() if ok else None


class RerunBridge:
    """Logs the messages of one rig to one Rerun recording (call from one thread)."""

    def __init__(self, rec: rr.RecordingStream) -> None:
        self.rec = rec
        self.trial = 0
        self.logged = 0
        self.last_t_ns: int | None = None
        self._layout: tuple[Any, ...] | None = None
        self._arm: dict[str, Any] = {}
        self._eyes: dict[str, Any] = {}
        self._cmd: tuple[Any, ...] | None = None
        self._gaze_state: str | None = None
        self.frames_dropped = 0  # vision frames that did not decode
        self.option_names: tuple[str, ...] = ()  # the options of the table as last laid out
        self.bars_sent = False  # the blueprint with bar charts, sent on the first N > 2 vector

    def log_styles(self) -> None:
        """Static names and colours of the series (once, before any data)."""
        for topic, (name, colour) in SCALAR_STYLE.items():
            self.rec.log(ENTITIES[topic], rr.SeriesLines(names=name, colors=colour), static=True)
        self.rec.log(ENTITIES["gaze_yaw"], rr.SeriesLines(names="yaw ψ"), static=True)
        self.rec.log(ENTITIES["gaze_pitch"], rr.SeriesLines(names="pitch φ"), static=True)
        self.rec.log(ENTITIES["servos"], rr.SeriesLines(names=list(SERVO_NAMES)), static=True)
        # Point styles once: the 120 Hz rows then carry positions only (half the logging cost).
        hand = rr.Points2D.from_fields(radii=0.006, colors=(240, 200, 40))
        self.rec.log(ENTITIES["hand"], hand, static=True)
        arm = rr.Points2D.from_fields(radii=0.008, labels=["arm"], show_labels=True)
        self.rec.log(ENTITIES["arm"], arm, static=True)
        self.rec.log(ENTITIES["arm_link"], rr.LineStrips2D.from_fields(radii=0.004), static=True)
        gaze = rr.Arrows2D.from_fields(radii=0.003, colors=GAZE_COLOUR)
        self.rec.log(ENTITIES["gaze"], gaze, static=True)

    # -- dispatch ------------------------------------------------------------------------------

    def log(self, topic: str, msg: m.Message) -> None:
        """Log one decoded message of `topic` (e.g. "vision/hand") at its own timestamp."""
        handler = getattr(self, f"_on_{msg.KIND}", None)
        if handler is None or topic in NOT_SHOWN:
            return
        if isinstance(msg, m.TrialEvent | m.TrialResult):
            self.trial = msg.trial  # before stamping: an event belongs to its own trial
        self._stamp(msg.t_ns)
        handler(topic, msg)
        self.logged += 1

    def note(self, text: str, level: str = "INFO", t_ns: int | None = None) -> None:
        """A line from the monitor itself (service liveliness, drops) on `log/services`."""
        stamp = t_ns if t_ns is not None else self.last_t_ns
        if stamp is not None:
            self._stamp(stamp)
        self.rec.log(ENTITIES["log_services"], rr.TextLog(text, level=level))

    def _stamp(self, t_ns: int) -> None:
        self.last_t_ns = t_ns if self.last_t_ns is None else max(self.last_t_ns, t_ns)
        self.rec.set_time(TIMELINE, timestamp=np.datetime64(t_ns, "ns"))
        self.rec.set_time(TRIAL_TIMELINE, sequence=self.trial)

    # -- vision --------------------------------------------------------------------------------

    def _on_hand(self, topic: str, msg: m.HandPose) -> None:
        if msg.detected and msg.center is not None:
            self.rec.log(ENTITIES["hand"], rr.Points2D([msg.center]))

    def _on_layout(self, topic: str, msg: m.Layout) -> None:
        """The boxes in their options' colours, labelled by name, and the commit line."""
        names, boxes, commit_y = tuple(msg.options), tuple(msg.boxes), msg.commit_y
        key = (names, boxes, commit_y)
        if key == self._layout:
            return  # re-published every second; log only what changed
        self._layout, self.option_names = key, names
        # Static: always drawn, whatever the time cursor or the table's trail window.
        self.rec.log(
            ENTITIES["buzzers"],
            rr.Boxes2D(
                array=np.array(boxes, dtype=np.float32),
                array_format=rr.Box2DFormat.XYXY,
                colors=[box_colour(n) for n in names],
                labels=list(names),
            ),
            static=True,
        )
        self.rec.log(
            ENTITIES["commit_line"],
            rr.LineStrips2D(
                [[(0.0, commit_y), (1.0, commit_y)]],
                colors=(128, 128, 128),
                labels=["commit line"],
            ),
            static=True,
        )

    def _on_frame(self, topic: str, msg: Any) -> None:
        jpeg = fit_frame(msg.jpeg)
        if jpeg is None:
            self.frames_dropped += 1
            if self.frames_dropped == 1:
                self.note(f"a frame on {topic} is not a JPEG: not shown", "WARN")
            return
        self.rec.log(ENTITIES["frame"], rr.EncodedImage(contents=jpeg, media_type="image/jpeg"))

    # -- decision ------------------------------------------------------------------------------

    def _on_opinions(self, topic: str, msg: m.Opinions) -> None:
        """ẑ_h, z_r or b_r: two options, the signed value's time series; more, a bar chart."""
        if len(msg.values) == 2:
            path = ENTITIES.get(topic)
            if path is not None:
                self.rec.log(path, rr.Scalars(msg.signed))
            return
        path = ENTITIES.get("bars/" + topic.removeprefix("decision/"))
        if path is None:
            return
        if not self.bars_sent:  # the first N-option vector: the layout shows bars
            self.bars_sent = True
            self.rec.send_blueprint(blueprint(bars=True))
        self.rec.log(path, rr.BarChart(np.asarray(msg.values, dtype=np.float64)))

    # ẑ_h also carries eq 7's θ and d: its values are plotted like z_r's and b_r's.
    _on_observed = _on_opinions

    # -- actuation -----------------------------------------------------------------------------

    def _on_arm_state(self, topic: str, msg: m.ArmStateMsg) -> None:
        """The end effector, the arm's segment, its phase lane and its safety lines."""
        ee, phase, safe_stop = msg.ee, msg.phase, msg.safe_stop
        reason, fault = msg.safety_reason, msg.fault
        prev = self._arm
        if prev.get("safe_stop") != safe_stop:  # red while safe-stopped
            colour = (230, 60, 60) if safe_stop else (90, 200, 250)
            self.rec.log(ENTITIES["arm"], rr.Points2D.from_fields(colors=colour))
            self.rec.log(ENTITIES["arm_link"], rr.LineStrips2D.from_fields(colors=colour))
        self.rec.log(ENTITIES["arm"], rr.Points2D([ee]))
        self.rec.log(ENTITIES["arm_link"], rr.LineStrips2D([[ARM_BASE, ee]]))
        if prev.get("phase") != phase:
            self.rec.log(ENTITIES["state_arm"], rr.StateChange(state=phase))
        self._safety("arm", prev, safe_stop, reason, fault)
        self._arm = {
            "phase": phase,
            "safe_stop": safe_stop,
            "reason": _NUMBERS.sub("#", reason),
            "fault": fault,
        }

    def _on_arm_cmd(self, topic: str, msg: m.ArmCommandMsg) -> None:
        key = (msg.action, msg.direction, msg.target)
        if key == self._cmd:
            return  # the 10 Hz repeat of the same command
        self._cmd = key
        target = f" → {msg.target}" if msg.target else ""
        reason = f" ({msg.reason})" if msg.reason else ""
        self.rec.log(
            ENTITIES["log_arm"],
            rr.TextLog(f"arm {msg.action}{target} dir {msg.direction:+d}{reason}", level="DEBUG"),
        )

    def _on_press(self, topic: str, msg: m.PressMsg) -> None:
        self.rec.log(
            ENTITIES["log_trial"],
            rr.TextLog(f"trial {msg.trial}: robot pressed {msg.option}", level="INFO"),
        )

    # -- eyes ----------------------------------------------------------------------------------

    def _on_gaze(self, topic: str, msg: m.GazeMsg) -> None:
        self.rec.log(ENTITIES["gaze_yaw"], rr.Scalars(msg.yaw))
        self.rec.log(ENTITIES["gaze_pitch"], rr.Scalars(msg.pitch))
        origins, vectors = gaze_arrows(msg.yaw)
        self.rec.log(ENTITIES["gaze"], rr.Arrows2D(origins=origins, vectors=vectors))
        state = f"{msg.level} + gesture" if msg.gesture else msg.level
        if state != self._gaze_state:
            self._gaze_state = state
            self.rec.log(ENTITIES["state_gaze"], rr.StateChange(state=state))

    def _on_eyes_state(self, topic: str, msg: m.EyesStateMsg) -> None:
        self.rec.log(ENTITIES["servos"], rr.Scalars(np.asarray(msg.angles_deg, dtype=np.float64)))
        prev = self._eyes
        self._safety("eyes", prev, msg.safe_stop, msg.safety_reason, msg.fault)
        if msg.clamped and tuple(msg.clamped) != prev.get("clamped"):
            self.rec.log(
                ENTITIES["log_safety"],
                rr.TextLog(f"eyes: servo target clamped: {', '.join(msg.clamped)}", level="WARN"),
            )
        self._eyes = {
            "safe_stop": msg.safe_stop,
            "reason": _NUMBERS.sub("#", msg.safety_reason),
            "fault": msg.fault,
            "clamped": tuple(msg.clamped),
        }

    def _safety(
        self, who: str, prev: dict[str, Any], safe_stop: bool, reason: str, fault: str
    ) -> None:
        """Text-log safe-stop and fault transitions of the arm or the eyes."""
        was = prev.get("safe_stop", False)
        # A reason like "gaze stale (257 ms)" changes every message; log when its words change.
        if safe_stop and (not was or _NUMBERS.sub("#", reason) != prev.get("reason")):
            self.rec.log(
                ENTITIES["log_safety"],
                rr.TextLog(f"{who}: SAFE STOP ({reason or 'no reason given'})", level="WARN"),
            )
        elif was and not safe_stop:
            self.rec.log(
                ENTITIES["log_safety"], rr.TextLog(f"{who}: safe stop cleared", level="INFO")
            )
        if fault != prev.get("fault", ""):
            text = f"{who}: FAULT {fault}" if fault else f"{who}: fault cleared"
            self.rec.log(
                ENTITIES["log_safety"], rr.TextLog(text, level="ERROR" if fault else "INFO")
            )

    # -- experiment and safety -----------------------------------------------------------------

    def _on_trial(self, topic: str, msg: m.TrialEvent) -> None:
        self.rec.log(ENTITIES["state_trial"], rr.StateChange(state=msg.phase))
        if msg.phase == "setup":
            option = f" O={msg.option}" if msg.option is not None else ""
            text = f"trial {msg.trial} setup: {msg.mode}{option}, gaze {_opt(msg.text)}"
        elif msg.phase == "countdown":
            text = f"trial {msg.trial} countdown {msg.text}"
        else:
            extra = f": {msg.text}" if msg.text and msg.text != msg.phase else ""
            text = f"trial {msg.trial} {msg.phase}{extra}"
        level = "WARN" if msg.phase == "abort" else "INFO"
        self.rec.log(ENTITIES["log_trial"], rr.TextLog(text, level=level))

    def _on_result(self, topic: str, msg: m.TrialResult) -> None:
        option = f" O={msg.option}" if msg.option is not None else ""
        text = (
            f"trial {msg.trial} [{msg.mode}{option}]: robot {_opt(msg.robot)}, human "
            f"{_opt(msg.human)} → {_opt(msg.outcome)} (switches {msg.switches}, violations "
            f"{msg.violations}, score {msg.score})"
        )
        if msg.interrupted:
            text += ": interrupted, not scored"
        level = "WARN" if msg.interrupted else "INFO"
        self.rec.log(ENTITIES["log_result"], rr.TextLog(text, level=level))

    def _on_rig_event(self, topic: str, msg: m.RigEvent) -> None:
        level = {"gave_up": "ERROR", "restarting": "WARN", "exited": "WARN"}.get(msg.kind, "INFO")
        if msg.kind == "exited" and msg.code == 0:
            level = "INFO"
        where = f"{msg.host}: " if msg.host else ""
        text = f"{where}{msg.service} {msg.kind.replace('_', ' ')}: {msg.text}"
        self.rec.log(ENTITIES["log_services"], rr.TextLog(text, level=level))

    def _on_estop(self, topic: str, msg: m.Estop) -> None:
        who = f" by {msg.source}" if msg.source else ""
        why = f": {msg.reason}" if msg.reason else ""
        if msg.engaged:
            self.rec.log(ENTITIES["log_safety"], rr.TextLog(f"ESTOP{who}{why}", level="ERROR"))
        else:
            self.rec.log(
                ENTITIES["log_safety"], rr.TextLog(f"estop released{who}{why}", level="WARN")
            )


def rrd_rows(path: str | Path) -> tuple[dict[str, int], dict[str, int]]:
    """Rows per entity path of a saved recording: (temporal rows, static rows).

    A quick check of what a `--save` file holds, e.g. `rrd_rows("s.rrd")[0]["/opinion/z_h"]`.
    """
    from rerun.chunk import RrdReader

    temporal: dict[str, int] = {}
    static: dict[str, int] = {}
    for chunk in RrdReader(path).stream():
        into = static if chunk.is_static else temporal
        into[chunk.entity_path] = into.get(chunk.entity_path, 0) + chunk.num_rows
    return temporal, static
