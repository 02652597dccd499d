"""Arm drivers: one small interface, and the simulated arm's press poses over N ≥ 2 boxes.

Following LeRobot's `Robot`: hardware sits behind `connect / is_connected / send / disconnect`
and a context manager; `send` returns the command actually applied (a driver may refuse or
change one, e.g. a move while a press is under way, or anything but a stop while faulted).
Leaving the `with` block holds the arm before disconnecting.

Coordinates are the table's normalised image coordinates (x right, y down, in [0, 1]); time is
in seconds (float) and always passed in — no driver here reads a clock.

Both simulated arms are `PointArm` (`services.model.arm_kinematics`: limits, braking, the press
hold) with one press pose per box, its centre; they differ only in how a target is named.
`OptionsSimArm` is the general form: option j of N heads for `layout.boxes[j]`, driven by
`OptionsCommand`s. `SimArm` is its two-option kernel, kept because the paper's rig speaks in
colours (`ArmCommand`, `ArmState`, the `ArmDriver` interface the Feetech driver shares): red
and blue of a `TableLayout`. On the paper's table (`OptionsLayout.from_table`, option 0 red)
the two apply the same commands and move bit for bit alike
(tests/unit/test_sim_arm.py, hypothesis).
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass

from services.model.arm_kinematics import PointArm, SimArmParams
from services.model.behaviour import ArmCommand, OptionsCommand
from services.model.device import Device
from services.model.geometry import Colour, OptionsLayout, Point, TableLayout


@dataclass(frozen=True, slots=True)
class ArmState:
    """What the arm reports at time t (s)."""

    t: float  # time of the report (s)
    ee: Point  # end effector in table coordinates
    moving: bool  # the end effector has non-zero velocity
    target: Colour | None  # buzzer the arm is heading for or pressing; None when stopping/home
    pressed: Colour | None  # buzzer the arm has finished pressing in this trial
    fault: str | None  # why the arm refuses motion, or None when healthy


class ArmDriver(Device):
    """The interface every arm (simulated or real) implements; its safe state is `hold`."""

    @abstractmethod
    def send(self, cmd: ArmCommand) -> ArmCommand:
        """Apply a command; return the command actually applied."""

    @abstractmethod
    def home(self) -> ArmCommand:
        """Drive back to the home pose and clear the trial's press (between trials)."""

    @abstractmethod
    def state(self, t: float) -> ArmState:
        """The arm's state at time t (s)."""

    def hold(self) -> ArmCommand:
        """Safe stop: come to rest (bounded deceleration) and hold that position."""
        return self.send(ArmCommand.stop("hold"))

    def make_safe(self) -> ArmCommand:
        """Hold the arm (before disconnecting)."""
        return self.hold()


class SimArm(PointArm[Colour], ArmDriver):
    """The paper's simulated arm: `PointArm` over the two buzzers, driven by `ArmCommand`s.

    "move" heads for the centre of that colour's box; "press" does the same, then holds the
    buzzer for `press_duration_s` and reports it pressed. "stop" brakes and then holds.
    """

    def __init__(
        self, layout: TableLayout, params: SimArmParams | None = None, t0: float = 0.0
    ) -> None:
        """Place the arm at home, at rest, at time t0 (s); not yet connected."""
        super().__init__(params, t0)
        self.layout = layout
        self._applied: ArmCommand = ArmCommand.idle("at home")

    # -- commands --------------------------------------------------------------------------
    def send(self, cmd: ArmCommand) -> ArmCommand:
        """Apply a command at the arm's current time; return what was actually applied.

        Refused (the returned command says what happens instead): anything but idle/stop while
        faulted (→ stop); a move, or a press of the other buzzer, once a press is committed
        (→ the committed press). A stop always applies and cancels an unfinished press.
        """
        self._require_connected()
        if cmd.action == "idle":
            return cmd
        if cmd.action == "stop":
            self._brake()
            return self._apply(cmd)
        if self._fault is not None:
            self._brake()
            return self._apply(ArmCommand.stop(f"refused {cmd.action}: fault {self._fault}"))
        if self._press is not None and cmd.target != self._press:
            return ArmCommand.press(self._press, f"refused {cmd.action}: press already committed")
        assert cmd.target is not None  # move and press always carry a target
        self._head(cmd.target, self.layout.box(cmd.target).center, cmd.action == "press")
        return self._apply(cmd)

    def home(self) -> ArmCommand:
        """Drive back to the home pose and clear the trial's press (refused while faulted)."""
        self._require_connected()
        if self._fault is not None:
            self._brake()
            return self._apply(ArmCommand.stop(f"refused home: fault {self._fault}"))
        self._go_home()
        return self._apply(ArmCommand.idle("going home"))

    def state(self, t: float) -> ArmState:
        """Advance to time t (s) and report."""
        self._require_connected()
        self.advance(t)
        return ArmState(
            t=self._t,
            ee=self._pos,
            moving=self._vel != (0.0, 0.0),
            target=self._target,
            pressed=self._pressed,
            fault=self._fault,
        )

    def _apply(self, cmd: ArmCommand) -> ArmCommand:
        self._applied = cmd
        return cmd


@dataclass(frozen=True, slots=True)
class OptionsArmState:
    """What the arm reports at time t (s); targets are option indices."""

    t: float
    ee: Point
    moving: bool
    target: int | None  # the box it heads for or presses; None when stopping or going home
    pressed: int | None  # the box it finished pressing this trial
    fault: str | None


class OptionsSimArm(PointArm[int]):
    """A kinematic arm over the N_o boxes of an `OptionsLayout`."""

    def __init__(
        self, layout: OptionsLayout, params: SimArmParams | None = None, t0: float = 0.0
    ) -> None:
        """Place the arm at home, at rest, at time t0 (s); not yet connected."""
        super().__init__(params, t0)
        self.layout = layout

    def pose(self, option: int) -> Point:
        """Where the end effector goes for option j: the centre of its box."""
        return self.layout.boxes[option].center

    def send(self, cmd: OptionsCommand) -> OptionsCommand:
        """Apply a command at the arm's current time; return what was actually applied.

        The refusals of `SimArm.send`: anything but idle/stop while faulted (→ stop); a move,
        or a press of another box, once a press is committed (→ the committed press).
        """
        self._require_connected()
        if cmd.action == "idle":
            return cmd
        if cmd.action == "stop":
            self._brake()
            return cmd
        if self._fault is not None:
            self._brake()
            return OptionsCommand("stop", reason=f"refused {cmd.action}: fault {self._fault}")
        if self._press is not None and cmd.target != self._press:
            return OptionsCommand(
                "press", self._press, f"refused {cmd.action}: press already committed"
            )
        assert cmd.target is not None  # move and press always carry a target
        if not 0 <= cmd.target < self.layout.n_options:
            raise ValueError(
                f"box {cmd.target} is not on this table of {self.layout.n_options} boxes"
            )
        self._head(cmd.target, self.pose(cmd.target), cmd.action == "press")
        return cmd

    def home(self) -> OptionsCommand:
        """Drive back to the home pose and clear the trial's press (refused while faulted)."""
        self._require_connected()
        if self._fault is not None:
            self._brake()
            return OptionsCommand("stop", reason=f"refused home: fault {self._fault}")
        self._go_home()
        return OptionsCommand("idle", reason="going home")

    def hold(self) -> OptionsCommand:
        """Safe stop: come to rest (bounded deceleration) and hold that position."""
        return self.send(OptionsCommand("stop", reason="hold"))

    def make_safe(self) -> OptionsCommand:
        """Hold the arm (before disconnecting), as the paper's arms do."""
        return self.hold()

    def state(self, t: float) -> OptionsArmState:
        """Advance to time t (s) and report."""
        self._require_connected()
        self.advance(t)
        return OptionsArmState(
            self._t, self._pos, self.moving, self._target, self._pressed, self._fault
        )
