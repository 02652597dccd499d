"""A Feetech STS/SCS servo arm (SO-100/SO-101) moving along calibrated poses, over N boxes.

The calibration file (`nod actuation calibrate`) holds a home pose and, for each option by name,
a pose above its buzzer and one pressing it; they span the arm's path (drawn in `arm_path.py`):
a spoke from home out to above each box, then a descent. The arm's place is a box, a progress
`u` along its spoke (0 at home, 1 above the buzzer) and a descent `d` (0 above the buzzer, 1 on
it); joint goals interpolate linearly between the poses, so every goal lies between calibrated
poses. "move" goes back along the spoke it is on to home if it heads for another box, then out
along the target's, at `1 / move_time_s` per second; "press" goes above the buzzer, descends in
`press_time_s`, holds `press_hold_s`, reports the press and rises again; the arm only moves
sideways with `d = 0`. Each `state(t)` advances the path to time t (s) and streams the new goals
in one SYNC_WRITE, so "stop" can halt mid-path and the next "move" may reverse from there
(Algorithm 2's stop–pause–reverse).

One driver for any N. Given the paper's `TableLayout` it speaks the paper's words (`ArmCommand`,
`ArmState`: red is box 0, blue box 1, and its path is the paper's s = ±u from red to blue through
home); given an `OptionsLayout` and the option names, the N-option words (`OptionsCommand`,
`OptionsArmState`, box j the poses of names[j]). The words are all that differs
(`arm_words.py`).

Safe stop holds the current position: it reads the present positions and writes them as goals.
On any bus fault (port gone, silence, corrupt status, servo error bits) the arm freezes its path,
reports `fault`, and keeps trying to reconnect; once the servos answer again it re-reads where
they are, writes that as the goal before torque is enabled (never a stale goal), and holds.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Generic, cast, overload

from services.actuation.arm_path import ArmPoses, Pose, locate_on, pose_on
from services.actuation.arm_words import OPTION_WORDS, PAPER_WORDS, ArmWords, C, R, T
from services.actuation.feetech import RESOLUTION, FeetechBus, Series
from services.core.serial_link import LinkConfig, LinkedDevice, LinkError, SerialLink
from services.model.arm import ArmState, OptionsArmState
from services.model.arm_kinematics import ArmNotConnectedError
from services.model.behaviour import ArmCommand, OptionsCommand
from services.model.checks import require_non_negative, require_positive
from services.model.geometry import COLOURS, Colour, OptionsLayout, Point, TableLayout

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class FeetechArmConfig:
    """The arm's bus and motion: the contents of the arm calibration file."""

    # Servo ids on the bus, one per joint (SO-101: pan, lift, elbow, wrist flex, roll, gripper).
    ids: tuple[int, ...] = (1, 2, 3, 4, 5, 6)
    # Servo family: "sts" (STS3215 of the SO-100/101; 4096 steps, little endian) or "scs".
    series: Series = "sts"
    # Bus baud rate (bit/s); the STS factory setting is 1 000 000.
    baudrate: int = 1_000_000
    # Time from home to above a buzzer (s); > 0. Sets the path speed; reversing mid-path and
    # pressing take proportionally less.
    move_time_s: float = 2.0
    # Time to descend from above a buzzer onto it, and to rise again (s); > 0.
    press_time_s: float = 0.6
    # Time the buzzer is held down before the press counts (s); >= 0.
    press_hold_s: float = 0.3
    # Servo speed cap written with every goal (steps/s, 0 = unlimited); bounds any jump, e.g.
    # the first move after the arm was pushed off its path. 1500 steps/s ≈ 130°/s.
    goal_speed: int = 1500
    # Servo acceleration register (100 steps/s² per unit, 0 = unlimited); 0–254.
    acceleration: int = 50
    # Interval between health reads of the present positions, and between reconnect attempts
    # of the servos after a fault (s); > 0.
    poll_interval_s: float = 0.2
    # Calibrated joint poses: home, and above/press for each option by name ([poses]).
    poses: ArmPoses = field(default_factory=ArmPoses)
    link: LinkConfig = field(default_factory=LinkConfig)  # timeouts and reconnect backoff

    def __post_init__(self) -> None:
        if not self.ids or len(set(self.ids)) != len(self.ids):
            raise ValueError(f"FeetechArmConfig.ids must be distinct, got {self.ids}")
        if not all(0 <= i <= 0xFD for i in self.ids):
            raise ValueError(f"FeetechArmConfig.ids must be in [0, 253], got {self.ids}")
        if self.series not in RESOLUTION:
            raise ValueError(f"FeetechArmConfig.series must be one of {sorted(RESOLUTION)}")
        if self.baudrate <= 0:
            raise ValueError(f"FeetechArmConfig.baudrate must be > 0, got {self.baudrate}")
        require_positive(self, "move_time_s", "press_time_s", "poll_interval_s")
        require_non_negative(self, "press_hold_s")
        if not 0 <= self.goal_speed <= 0x7FFF or not 0 <= self.acceleration <= 254:
            raise ValueError(
                "FeetechArmConfig: goal_speed must be in [0, 32767], acceleration in [0, 254]"
            )
        top = RESOLUTION[self.series] - 1
        for name, pose in self.poses.table().items() if self.poses.calibrated else ():
            if len(pose) != len(self.ids):
                raise ValueError(
                    f"pose {name} has {len(pose)} joints but there are {len(self.ids)} ids"
                )
            if not all(0 <= p <= top for p in pose):
                raise ValueError(f"pose {name} must lie in [0, {top}] steps, got {pose}")


# -- driver -------------------------------------------------------------------------------------
class FeetechArm(LinkedDevice, Generic[C, T, R]):
    """The arm on a Feetech bus over N boxes; `state(t)` drives the motion, time passed in (s).

    `FeetechArm(port, config, table_layout)` is the paper's arm (red and blue, `ArmCommand`);
    `FeetechArm(port, config, options_layout, names=…)` the arm over N boxes (`OptionsCommand`).
    """

    @overload
    def __init__(
        self: FeetechArm[ArmCommand, Colour, ArmState],
        port: str,
        config: FeetechArmConfig,
        layout: TableLayout,
        home: Point = (0.5, 0.08),
        *,
        link: SerialLink | None = None,
    ) -> None: ...

    @overload
    def __init__(
        self: FeetechArm[OptionsCommand, int, OptionsArmState],
        port: str,
        config: FeetechArmConfig,
        layout: OptionsLayout,
        home: Point = (0.5, 0.08),
        *,
        names: Sequence[str],
        link: SerialLink | None = None,
    ) -> None: ...

    def __init__(
        self,
        port: str,
        config: FeetechArmConfig,
        layout: TableLayout | OptionsLayout,
        home: Point = (0.5, 0.08),
        *,
        names: Sequence[str] = COLOURS,
        link: SerialLink | None = None,
    ) -> None:
        """Describe the arm; nothing is opened until `connect()`.

        Box j is option `names[j]`, pressed at the file's `press_<name>` pose (the paper's
        layout: red, blue). `layout` and `home` (table coordinates of the home pose) only feed
        the end-effector estimate of `state()`. A file without a pose for every name is
        refused in one line naming the missing options.
        """
        if not config.poses.calibrated:
            raise ValueError(
                "the arm file has no [poses]; record them with `nod actuation calibrate`"
            )
        paper = isinstance(layout, TableLayout)
        table = OptionsLayout.from_table(layout) if isinstance(layout, TableLayout) else layout
        if len(names) != table.n_options:
            raise ValueError(f"{len(names)} option names for a table of {table.n_options} boxes")
        # The overloads tie the words to the layout: the paper's for its table, else by index.
        words = PAPER_WORDS if paper else OPTION_WORDS
        self.words = cast(ArmWords[C, T, R], words)
        self.names = tuple(names)
        self.poses = config.poses.select(self.names)  # box j: the poses of option names[j]
        self.config = config
        self.layout = layout
        self.centres = tuple(box.center for box in table.boxes)
        self.home_point = home
        self.link = link if link is not None else SerialLink(port, config.baudrate, config.link)
        self.bus = FeetechBus(self.link, config.series)
        self._connected = False
        self._generation = -1
        self._t: float | None = None
        self._box = 0  # the spoke the arm is on (any at home)
        self._u = 0.0  # progress along it: 0 home, 1 above the buzzer
        self._d = 0.0  # descent: 0 above the buzzer, 1 pressing it
        self._mode: str = "hold"  # hold | move | home | press
        self._goal: int | None = None  # the box heading for; None: home
        self._target: T | None = None
        self._press: T | None = None
        self._dwell = 0.0  # time the buzzer has been held down (s)
        self._pressed: T | None = None
        self._moving = False
        self._fault: str | None = None
        self._next_try = -math.inf  # arm time of the next health read / re-initialisation
        self.present: Pose | None = None  # latest present positions read from the servos
        self.last_goal: Pose | None = None  # latest goals written

    # -- connection ----------------------------------------------------------------------------
    @property
    def place(self) -> tuple[int, float, float]:
        """(box, u, d): where the arm is on its calibrated path."""
        return self._box, self._u, self._d

    @property
    def path(self) -> tuple[float, float]:
        """(s, d) on the paper's path: s = u toward box 0 (red), −u toward box 1 (blue)."""
        return (self._u if self._box == 0 else -self._u), self._d

    def connect(self) -> None:
        """Open the port, find every servo, hold where the arm is, torque on."""
        if self._connected:
            return
        self._open_link(
            "the Feetech arm",
            f"check the servo power supply, the ids {list(self.config.ids)} and the baud rate "
            f"{self.config.baudrate} in the arm file",
        )
        self._connected = True

    def disconnect(self) -> None:
        """Close the port (idempotent); the servos keep holding their last goal."""
        self._connected = False
        self.link.close()

    # -- commands ------------------------------------------------------------------------------
    def send(self, cmd: C) -> C:
        """Apply a command at the arm's current time (call `state(t)` first).

        Refused (the returned command says what happens instead): anything but idle/stop while
        faulted (→ stop); a move, or a press of another box, once a press is committed (→ the
        committed press). A stop always applies and cancels an unfinished press.
        """
        self._require_connected()
        if cmd.action == "idle":
            return cmd
        if cmd.action == "stop":
            self._hold_here()
            return cmd
        if self._fault is not None:
            self._hold_here()
            return self.words.stop(f"refused {cmd.action}: fault {self._fault}")
        target = self.words.target(cmd)
        if self._press is not None and target != self._press:
            return self.words.press(self._press, f"refused {cmd.action}: press already committed")
        assert target is not None  # move and press always carry a target
        box = self.words.box(target)
        if not 0 <= box < len(self.names):
            raise ValueError(f"box {box} is not on this table of {len(self.names)} boxes")
        if cmd.action == "press" and self._press is None:
            self._press, self._dwell, self._pressed = target, 0.0, None
        self._mode = "press" if self._press is not None else "move"
        self._goal, self._target = box, target
        return cmd

    def home(self) -> C:
        """Go back to the home pose and forget the trial's press (refused while faulted)."""
        self._require_connected()
        if self._fault is not None:
            self._hold_here()
            return self.words.stop(f"refused home: fault {self._fault}")
        self._press = self._pressed = None
        self._mode, self._goal, self._target = "home", None, None
        return self.words.idle("going home")

    def hold(self) -> C:
        """Safe stop: freeze the path and hold the present position."""
        return self.send(self.words.stop("hold"))

    def make_safe(self) -> C:
        """Hold the arm (before disconnecting)."""
        return self.hold()

    def state(self, t: float) -> R:
        """Advance the path to time t (s), stream the goals, keep the bus healthy; report."""
        self._require_connected()
        if not math.isfinite(t):
            raise ValueError(f"time must be finite, got {t!r}")
        if self._t is not None and t < self._t:
            raise ValueError(f"time went backwards: {t} < {self._t}; pass monotonic time")
        dt = 0.0 if self._t is None else t - self._t
        self._t = t
        self._moving = False
        if self._service_bus(t):
            before = self.place
            self._advance(dt)
            if self.place != before:
                if self._write(pose_on(self.poses, self._box, self._u, self._d)):
                    self._moving = True
                else:  # the servos never got this goal: the arm stands where it was
                    self._box, self._u, self._d = before
        return self.words.report(
            t, self.ee_estimate(), self._moving, self._target, self._pressed, self._fault
        )

    def ee_estimate(self) -> Point:
        """End effector in table coordinates, estimated from path progress (not kinematics).

        Linear between `home` and the centre of the box whose spoke the arm is on, by u;
        pressing does not move it. Good enough for Algorithm 2's "nearest buzzer".
        """
        box = self.centres[self._box]
        u = self._u
        return (
            self.home_point[0] + (box[0] - self.home_point[0]) * u,
            self.home_point[1] + (box[1] - self.home_point[1]) * u,
        )

    # -- motion (pure state updates) -----------------------------------------------------------
    def _spoke_leg(self) -> tuple[str, float] | None:
        """Along the spokes, up: back to home first if the goal is another box's, then out."""
        if self._goal is None or (self._goal != self._box and self._u > 0):
            return ("u", 0.0) if self._u > 0 else None
        return ("u", 1.0) if (self._box, self._u) != (self._goal, 1.0) else None

    def _leg(self) -> tuple[str, float] | None:
        """The next motion leg: ("u" | "d" | "dwell", goal), or None when at rest."""
        if self._mode == "hold":
            return None
        if self._mode in ("move", "home"):
            return ("d", 0.0) if self._d > 0 else self._spoke_leg()
        # press
        if self._pressed is not None:
            return ("d", 0.0) if self._d > 0 else None
        if (self._box, self._u) != (self._goal, 1.0):
            return ("d", 0.0) if self._d > 0 else self._spoke_leg()
        if self._d < 1:
            return "d", 1.0
        return "dwell", self.config.press_hold_s

    def _advance(self, dt: float) -> None:
        c = self.config
        while dt > 0:
            leg = self._leg()
            if leg is None:
                return
            kind, goal = leg
            if kind == "dwell":
                used = min(dt, goal - self._dwell)
                self._dwell += used
                dt -= used
                if self._dwell >= goal:
                    self._pressed = self._press
                    log.info("pressed the %s buzzer", self.names[self._box])
                continue
            if kind == "u" and goal > 0 and self._goal is not None:
                self._box = self._goal  # out along the goal's spoke (from home, or on it)
            rate = 1.0 / (c.move_time_s if kind == "u" else c.press_time_s)
            now = self._u if kind == "u" else self._d
            need = abs(goal - now) / rate
            if need <= dt:
                new, dt = goal, dt - need
            else:
                new, dt = now + math.copysign(dt * rate, goal - now), 0.0
            if kind == "u":
                self._u = new
            else:
                self._d = new

    def _hold_here(self) -> None:
        """Safe stop: freeze the path, cancel an unfinished press, hold the present position."""
        self._mode, self._target = "hold", None
        if self._pressed is None:
            self._press = None
        if self._fault is None and self.link.is_open:
            try:
                self._write(self.bus.read_positions(self.config.ids))
            except LinkError as exc:
                self._set_fault(exc)

    # -- bus -----------------------------------------------------------------------------------
    def _write(self, goals: Pose) -> bool:
        """Stream goals to every servo; False (and a fault) when the bus failed."""
        try:
            goal_map = dict(zip(self.config.ids, goals, strict=True))
            self.bus.write_goals(goal_map, self.config.goal_speed)
        except LinkError as exc:
            self._set_fault(exc)
            return False
        self.last_goal = goals
        return True

    def _initialise(self) -> None:
        """Find the servos and hold them where they are; torque on last."""
        c = self.config
        for servo_id in c.ids:
            self.bus.ping(servo_id)
        present = self.bus.read_positions(c.ids)
        self.bus.write_goals(dict(zip(c.ids, present, strict=True)), c.goal_speed)  # no stale goal
        for servo_id in c.ids:
            self.bus.write_register(servo_id, "acceleration", c.acceleration)
        self.bus.set_torque(c.ids, True)
        self.present = self.last_goal = present
        self._box, self._u, self._d = locate_on(self.poses, present)
        self._generation = self.link.opens
        self._fault = None
        self.link.ok()

    def _service_bus(self, t: float) -> bool:
        """Reconnect / re-initialise / health-read as due; True when the bus is healthy."""
        if not self.link.ensure_open():
            self._set_fault(self.link.fault or f"{self.link.port} is closed")
            return False
        due = t >= self._next_try
        if self._fault is not None or self.link.opens != self._generation:
            if not due:
                return False
            self._next_try = t + self.config.poll_interval_s
            try:
                self._initialise()
            except LinkError as exc:
                self._set_fault(exc)
                return False
            log.info("Feetech arm on %s healthy again; holding", self.link.port)
            return True
        if due:
            self._next_try = t + self.config.poll_interval_s
            try:
                self.present = self.bus.read_positions(self.config.ids)
                self.link.ok()
            except LinkError as exc:
                self._set_fault(exc)
                return False
        return True

    def _set_fault(self, why: LinkError | str) -> None:
        message = f"feetech: {why}"
        if self._fault is None:
            log.warning("%s; arm frozen", message)
        self._fault = message
        self._mode, self._target = "hold", None
        if self._pressed is None:
            self._press = None

    def _require_connected(self) -> None:
        if not self._connected:
            raise ArmNotConnectedError("the arm is not connected; call connect() first")
