"""A Feetech STS/SCS servo arm (SO-100/SO-101) moving along calibrated poses.

Five joint poses from the calibration file (`nod actuation calibrate`) span the arm's path
(drawn in `arm_path.py`). The arm's place is a path parameter `s` (0 at home, +1 above red, −1
above blue) and a descent `d` (0 above the buzzer, 1 on it); joint goals interpolate linearly
between the poses, so every goal lies between calibrated poses. "move" advances `s` toward ±1 at
`1 / move_time_s` per second; "press" goes above the buzzer, descends in `press_time_s`, holds
`press_hold_s`, reports the press and rises again; the arm only moves sideways with `d = 0`.
Each `state(t)` advances the path to time t (s) and streams the new goals in one SYNC_WRITE, so
"stop" can halt mid-path and the next "move" may reverse from there (Algorithm 2's
stop–pause–reverse).

Safe stop holds the current position: it reads the present positions and writes them as goals.
On any bus fault (port gone, silence, corrupt status, servo error bits) the arm freezes its path,
reports `fault`, and keeps trying to reconnect; once the servos answer again it re-reads where
they are, writes that as the goal before torque is enabled (never a stale goal), and holds.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

from services.actuation.arm_path import POSE_NAMES, ArmPoses, Pose, locate, pose_at
from services.actuation.feetech import RESOLUTION, FeetechBus, Series
from services.core.serial_link import LinkConfig, LinkedDevice, LinkError, SerialLink
from services.model.arm import ArmDriver, ArmState
from services.model.arm_kinematics import ArmNotConnectedError
from services.model.behaviour import ArmCommand
from services.model.checks import require_non_negative, require_positive
from services.model.geometry import Colour, Point, TableLayout, colour_sign

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
    poses: ArmPoses = field(default_factory=ArmPoses)  # calibrated joint poses
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
        for name in POSE_NAMES if self.poses.calibrated else ():
            pose = getattr(self.poses, name)
            if len(pose) != len(self.ids):
                raise ValueError(
                    f"pose {name} has {len(pose)} joints but there are {len(self.ids)} ids"
                )
            if not all(0 <= p <= top for p in pose):
                raise ValueError(f"pose {name} must lie in [0, {top}] steps, got {pose}")


# -- driver -------------------------------------------------------------------------------------
class FeetechArm(LinkedDevice, ArmDriver):
    """The arm on a Feetech bus; `state(t)` drives the motion, time passed in (s)."""

    def __init__(
        self,
        port: str,
        config: FeetechArmConfig,
        layout: TableLayout,
        home: Point = (0.5, 0.08),
        *,
        link: SerialLink | None = None,
    ) -> None:
        """Describe the arm; nothing is opened until `connect()`.

        `layout` and `home` (table coordinates of the home pose) only feed the end-effector
        estimate of `state()`.
        """
        if not config.poses.calibrated:
            raise ValueError(
                "the arm file has no [poses]; record them with `nod actuation calibrate`"
            )
        self.config = config
        self.layout = layout
        self.home_point = home
        self.link = link if link is not None else SerialLink(port, config.baudrate, config.link)
        self.bus = FeetechBus(self.link, config.series)
        self._connected = False
        self._generation = -1
        self._t: float | None = None
        self._s = 0.0  # path parameter: 0 home, +1 above red, −1 above blue
        self._d = 0.0  # descent: 0 above the buzzer, 1 pressing it
        self._mode: str = "hold"  # hold | move | home | press
        self._goal_s = 0.0
        self._target: Colour | None = None
        self._press: Colour | None = None
        self._dwell = 0.0  # time the buzzer has been held down (s)
        self._pressed: Colour | None = None
        self._moving = False
        self._fault: str | None = None
        self._next_try = -math.inf  # arm time of the next health read / re-initialisation
        self.present: Pose | None = None  # latest present positions read from the servos
        self.last_goal: Pose | None = None  # latest goals written

    # -- connection ----------------------------------------------------------------------------
    @property
    def path(self) -> tuple[float, float]:
        """(s, d): where the arm is on its calibrated path."""
        return self._s, self._d

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
    def send(self, cmd: ArmCommand) -> ArmCommand:
        """Apply a command at the arm's current time (call `state(t)` first)."""
        self._require_connected()
        if cmd.action == "idle":
            return cmd
        if cmd.action == "stop":
            self._hold_here()
            return cmd
        if self._fault is not None:
            self._hold_here()
            return ArmCommand.stop(f"refused {cmd.action}: fault {self._fault}")
        if self._press is not None and cmd.target != self._press:
            return ArmCommand.press(self._press, f"refused {cmd.action}: press already committed")
        assert cmd.target is not None  # move and press always carry a target
        if cmd.action == "press" and self._press is None:
            self._press, self._dwell, self._pressed = cmd.target, 0.0, None
        self._mode = "press" if self._press is not None else "move"
        self._goal_s = float(colour_sign(cmd.target))
        self._target = cmd.target
        return cmd

    def home(self) -> ArmCommand:
        """Go back to the home pose and forget the trial's press (refused while faulted)."""
        self._require_connected()
        if self._fault is not None:
            self._hold_here()
            return ArmCommand.stop(f"refused home: fault {self._fault}")
        self._press = self._pressed = None
        self._mode, self._goal_s, self._target = "home", 0.0, None
        return ArmCommand.idle("going home")

    def state(self, t: float) -> ArmState:
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
            before = (self._s, self._d)
            self._advance(dt)
            if (self._s, self._d) != before:
                if self._write(pose_at(self.config.poses, self._s, self._d)):
                    self._moving = True
                else:  # the servos never got this goal: the arm stands where it was
                    self._s, self._d = before
        return ArmState(
            t=t,
            ee=self.ee_estimate(),
            moving=self._moving,
            target=self._target,
            pressed=self._pressed,
            fault=self._fault,
        )

    def ee_estimate(self) -> Point:
        """End effector in table coordinates, estimated from path progress (not kinematics).

        Linear between `home` and the centre of the box on the side of s, by |s|; pressing
        does not move it. Good enough for Algorithm 2's "nearest buzzer".
        """
        box = self.layout.box("red" if self._s >= 0 else "blue").center
        u = abs(self._s)
        return (
            self.home_point[0] + (box[0] - self.home_point[0]) * u,
            self.home_point[1] + (box[1] - self.home_point[1]) * u,
        )

    # -- motion (pure state updates) -----------------------------------------------------------
    def _leg(self) -> tuple[str, float] | None:
        """The next motion leg: ("s" | "d" | "dwell", goal), or None when at rest."""
        if self._mode == "hold":
            return None
        if self._mode in ("move", "home"):
            if self._d > 0:
                return "d", 0.0
            return ("s", self._goal_s) if self._s != self._goal_s else None
        # press
        if self._pressed is not None:
            return ("d", 0.0) if self._d > 0 else None
        if self._s != self._goal_s:
            return ("d", 0.0) if self._d > 0 else ("s", self._goal_s)
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
                    log.info("pressed the %s buzzer", self._pressed)
                continue
            rate = 1.0 / (c.move_time_s if kind == "s" else c.press_time_s)
            now = self._s if kind == "s" else self._d
            need = abs(goal - now) / rate
            if need <= dt:
                new, dt = goal, dt - need
            else:
                new, dt = now + math.copysign(dt * rate, goal - now), 0.0
            if kind == "s":
                self._s = new
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
        self._s, self._d = locate(c.poses, present)
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
