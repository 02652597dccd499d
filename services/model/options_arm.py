"""The simulated arm over N_o boxes: `PointArm`'s kinematics with one pose per option.

The same body as the paper's `SimArm` (speed and acceleration limits, braking stops, a press
held `press_duration_s`), with option indices for targets: a "move" or "press" of option j
heads for the centre of `layout.boxes[j]`, and home is `SimArmParams.home` (midway on the
robot's side of the table). Driven by `OptionsCommand`s (`services.model.options_behaviour`).
"""

from __future__ import annotations

from dataclasses import dataclass

from services.model.arm import PointArm, SimArmParams
from services.model.geometry import Point
from services.model.options_behaviour import OptionsCommand
from services.model.options_geometry import OptionsLayout


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
            return OptionsCommand("press", self._press, "refused: press already committed")
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

    def state(self, t: float) -> OptionsArmState:
        """Advance to time t (s) and report."""
        self._require_connected()
        self.advance(t)
        return OptionsArmState(
            self._t, self._pos, self.moving, self._target, self._pressed, self._fault
        )
