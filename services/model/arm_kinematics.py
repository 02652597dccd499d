"""The simulated arm's kinematics: a point end effector with speed and acceleration limits.

`PointArm` is the body of every simulated arm (`services.model.arm`): it moves over the table
in normalised image coordinates (x right, y down, in [0, 1]), brakes at a bounded deceleration,
and holds a press `press_duration_s` before reporting it. Its targets are named by the arm that
uses it: a colour (the paper's two buzzers) or an option index (N boxes). Time is in seconds
(float) and always passed in: nothing here reads a clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

from services.model.checks import require_non_negative, require_positive
from services.model.compiled import A_SIZE, ArmSteps, arm_kernel
from services.model.compiled import enabled as compiled_enabled
from services.model.device import SimConnection
from services.model.geometry import Point

Target = TypeVar("Target")  # what a simulated arm's targets are named by: a colour, an option


class ArmNotConnectedError(RuntimeError):
    """A command or query reached an arm driver before `connect()` (or after `disconnect()`)."""


@dataclass(frozen=True, slots=True)
class SimArmParams:
    """Kinematic limits of the simulated arm."""

    # Rest pose: the robot sits across the table from the participant, near the top edge
    # between the two boxes (normalised image coordinates).
    home: Point = (0.5, 0.08)
    # Speed limit of the end effector (normalised units/s); > 0. Never exceeded.
    max_speed: float = 0.35
    # Acceleration limit (normalised units/s²); > 0. Also bounds braking: a stop is not instant.
    max_accel: float = 2.0
    # Time the buzzer is held down once reached (s); ≥ 0.
    press_duration_s: float = 0.3
    # Internal integration step (s); > 0. Smaller = more exact arrival, more work per advance.
    step_s: float = 0.002

    def __post_init__(self) -> None:
        if len(self.home) != 2 or not all(math.isfinite(v) for v in self.home):
            raise ValueError(f"SimArmParams.home must be a finite (x, y), got {self.home!r}")
        require_positive(self, "max_speed", "max_accel", "step_s")
        require_non_negative(self, "press_duration_s")


_ARRIVED = 1e-6  # distance (normalised) under which the arm snaps onto its goal


class PointArm(SimConnection, Generic[Target]):
    """A point end effector with speed and acceleration limits, moving over the table.

    The kinematics and the press hold of every simulated arm, whatever names its targets: a
    colour (`SimArm`, the paper's two buzzers) or an option index (`OptionsSimArm`, N boxes).
    `_head` drives toward a target's point, and holds it `press_duration_s` when it is a
    press; `_brake` brakes at `max_accel` (a real arm cannot stop instantly, so neither does
    this one) and then holds. Motion takes effect at the arm's current time: call `advance(t)`
    first.
    """

    def __init__(self, params: SimArmParams | None = None, t0: float = 0.0) -> None:
        """Place the arm at home, at rest, at time t0 (s); not yet connected."""
        self.params = params if params is not None else SimArmParams()
        if not math.isfinite(t0):
            raise ValueError(f"t0 must be finite, got {t0!r}")
        self._t = t0
        self._connected = False
        self._pos: Point = self.params.home
        self._vel: Point = (0.0, 0.0)
        self._goal: Point | None = None  # None: brake to rest and hold
        self._target: Target | None = None
        self._press: Target | None = None  # buzzer committed to press
        self._press_started: float | None = None
        self._pressed: Target | None = None
        self._fault: str | None = None
        self._steps: ArmSteps | None = None  # `use_compiled`: the substeps as machine code

    def use_compiled(self) -> None:
        """Take the substeps with the compiled loop (`compiled.arm_steps`), the same values.

        The offline loop's choice (`closed_loop`); the rig's simulated arm stays Python.
        """
        if compiled_enabled():
            self._steps = arm_kernel()

    # -- read-only state -------------------------------------------------------------------
    @property
    def t(self) -> float:
        """The arm's current time (s)."""
        return self._t

    @property
    def position(self) -> Point:
        """The end effector's current position."""
        return self._pos

    @property
    def velocity(self) -> Point:
        """The end effector's current velocity (normalised units/s)."""
        return self._vel

    @property
    def speed(self) -> float:
        """|velocity| (normalised units/s)."""
        return math.hypot(*self._vel)

    @property
    def moving(self) -> bool:
        """Whether the end effector has non-zero velocity."""
        return self._vel != (0.0, 0.0)

    def glance(self, t: float) -> tuple[Point, bool, Target | None, Target | None]:
        """Advance to time t (s); (end effector, moving, target, pressed), as `state(t)` has them.

        The offline loop's read of the arm once or twice a frame, without building the report
        (a frozen dataclass): the same values, ~10× quicker.
        """
        self._require_connected()
        self.advance(t)
        return self._pos, self._vel != (0.0, 0.0), self._target, self._pressed

    # -- faults ----------------------------------------------------------------------------
    def inject_fault(self, reason: str) -> None:
        """Simulate a hardware fault: brake, then refuse motion until `clear_fault`."""
        self._fault = reason
        self._brake()

    def clear_fault(self) -> None:
        """Clear a simulated fault; the arm stays at rest until the next command."""
        self._fault = None

    # -- kinematics ------------------------------------------------------------------------
    def advance(self, t: float) -> None:
        """Integrate the motion up to time t (s), in steps of at most `step_s`."""
        if not math.isfinite(t):
            raise ValueError(f"time must be finite, got {t!r}")
        if t < self._t:
            raise ValueError(f"time went backwards: {t} < {self._t}; pass monotonic time")
        span = t - self._t
        if span == 0:
            return
        n = max(1, math.ceil(span / self.params.step_s))
        if self._steps is not None and not (
            self._vel == (0.0, 0.0)
            and (self._goal is None or self._pos == self._goal)
            and (self._press is None or self._pressed is not None or self._goal is None)
        ):  # moving, or holding a press: the compiled substeps (at rest the loop stops at once)
            self._advance_compiled(self._steps, span, n)
            self._t = t
            return
        dt = span / n
        t0 = self._t
        for i in range(1, n + 1):
            if self._vel == (0.0, 0.0) and (self._goal is None or self._pos == self._goal):
                # At rest where it should be (the arm waits so most of a session): a substep
                # would leave position and velocity as they are, bit for bit; only a press
                # being held down goes on, and nothing at all without one.
                if self._press is None or self._pressed is not None or self._goal is None:
                    break
                self._update_press(t0 + span * i / n)
            else:
                self._substep(dt, t0 + span * i / n)
        self._t = t

    def _advance_compiled(self, steps: ArmSteps, span: float, n: int) -> None:
        """`advance`'s n substeps over span by `compiled.arm_steps`, the state in a vector."""
        goal, started = self._goal, self._press_started
        s = np.array(
            [*self._pos, *self._vel, *(goal or (0.0, 0.0)), goal is not None,
             self._press is not None, self._pressed is not None,
             0.0 if started is None else started, started is not None],
            dtype=np.float64,
        )
        p = self.params
        assert s.shape == (A_SIZE,)
        steps(self._t, span, n, s, p.max_speed, p.max_accel, p.press_duration_s)
        x, y, vx, vy, _, _, _, _, pressed, started, has_started = s.tolist()
        self._pos = (x, y)
        self._vel = (vx, vy)
        if has_started:
            self._press_started = started
        if pressed and self._pressed is None:
            self._pressed = self._press

    def _substep(self, dt: float, t_end: float) -> None:
        p = self.params
        goal = self._goal
        if goal is None:
            v_des = (0.0, 0.0)
        else:
            dx, dy = goal[0] - self._pos[0], goal[1] - self._pos[1]
            dist = math.hypot(dx, dy)
            if dist < _ARRIVED:
                v_des = (0.0, 0.0)
            else:
                # Brake in time to arrive at rest (v² = 2 a d), and never step past the goal.
                speed = min(p.max_speed, math.sqrt(2.0 * p.max_accel * dist), dist / dt)
                v_des = (dx / dist * speed, dy / dist * speed)
        vx, vy = v0 = self._vel
        ax, ay = v_des[0] - vx, v_des[1] - vy
        dv = math.hypot(ax, ay)
        dv_max = p.max_accel * dt
        if dv > dv_max:
            ax, ay = ax * dv_max / dv, ay * dv_max / dv
        vx, vy = vx + ax, vy + ay
        speed = math.hypot(vx, vy)
        if speed > p.max_speed:  # guard against rounding: the limit is a safety property
            vx, vy = vx * p.max_speed / speed, vy * p.max_speed / speed
        if speed < 1e-12:
            vx = vy = 0.0
        self._vel = (vx, vy)
        self._pos = (self._pos[0] + vx * dt, self._pos[1] + vy * dt)
        if goal is not None:
            dist = math.dist(self._pos, goal)
            # Snap onto the goal only if stopping from the step's *initial* velocity is itself
            # within this step's acceleration budget: the snap replaces the update, it must not
            # add a second velocity change on top of it.
            if dist < _ARRIVED and math.hypot(*v0) <= dv_max:
                self._pos, self._vel = goal, (0.0, 0.0)
        self._update_press(t_end)

    def _update_press(self, t: float) -> None:
        if self._press is None or self._pressed is not None or self._goal is None:
            return
        if self._pos != self._goal or self._vel != (0.0, 0.0):
            return
        if self._press_started is None:
            self._press_started = t
        if t - self._press_started >= self.params.press_duration_s - 1e-12:
            self._pressed = self._press

    # -- internals -------------------------------------------------------------------------
    def _head(self, target: Target, goal: Point, press: bool) -> None:
        """Drive toward `goal`, the point of `target`; commit to pressing it if `press`."""
        if press and self._press is None:
            self._press = target
            self._press_started = None
        self._goal = goal
        self._target = target

    def _go_home(self) -> None:
        """Drive back to the home pose and clear the trial's press."""
        self._press = self._pressed = self._press_started = None
        self._goal = self.params.home
        self._target = None

    def _brake(self) -> None:
        self._goal = None
        self._target = None
        if self._pressed is None:
            self._press = None  # an unfinished press is cancelled by a stop
            self._press_started = None

    def _require_connected(self) -> None:
        if not self._connected:
            raise ArmNotConnectedError("the arm is not connected; call connect() first")
