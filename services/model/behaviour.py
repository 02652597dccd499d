"""The robot's behaviour during one trial: paper Algorithm 2 as the prose of SPEC §4.

The pseudo-code in the paper is garbled (its last branch turns red whenever σ ≠ 0), so this
state machine implements the prose instead:

- after "go", start moving toward sgn(z_r) at the first non-zero z_r;
- a change of direction needs C_max consecutive samples of the new sign (`SignDebouncer`, the
  same debounce that counts the human's switches); then stop, pause `pause_s`, and move toward
  the new side. A shorter flip is ignored, and an interrupted flip resets the count;
- when the human pressed (a hand landmark inside a buzzer box) or the trial timed out, stop at
  once and press the buzzer nearest the end effector (`TableLayout.nearest`). The timeout is the
  protocol's (`ProtocolParams.trial_timeout_s`), passed to `start`: a trial has one timeout.

Phases: idle → waiting (after `start`) → moving ⇄ pausing → pressing → done. Safety is not a
phase: the actuation shell's watchdog holds the arm and the machine resumes when it clears. The
machine is pure: time is an argument in seconds (float, any monotonic origin, typically sim or
message time), and it never touches hardware — it returns an `ArmCommand` that a driver applies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, TypeAlias

from services.model.debounce import DebounceParams, SignDebouncer
from services.model.geometry import Colour, Point, TableLayout, colour_sign, sign_colour

Action: TypeAlias = Literal["idle", "stop", "move", "press"]
Phase: TypeAlias = Literal["idle", "waiting", "moving", "pausing", "pressing", "done"]


@dataclass(frozen=True, slots=True)
class BehaviourParams:
    """Tuning of Algorithm 2 (SPEC §4 defaults); C_max is `DebounceParams.c_max`."""

    # Stop before reversing (s); ≥ 0. The arm comes to rest before heading the other way.
    pause_s: float = 0.1

    def __post_init__(self) -> None:
        if not math.isfinite(self.pause_s) or self.pause_s < 0:
            raise ValueError(f"BehaviourParams.pause_s must be finite and >= 0, got {self.pause_s}")


@dataclass(frozen=True, slots=True)
class ArmCommand:
    """One command for the arm.

    `direction` is +1 toward red, −1 toward blue, 0 for no motion. A "move" carries the colour it
    heads for in `target`; a "press" carries the buzzer to press (and its sign as direction);
    "idle" and "stop" carry neither. `reason` is a short human-readable cause, for logs.
    """

    action: Action
    direction: int = 0
    target: Colour | None = None
    reason: str = ""

    def __post_init__(self) -> None:
        if self.action in ("idle", "stop"):
            if self.direction != 0 or self.target is not None:
                raise ValueError(f"an {self.action!r} command has no direction or target: {self}")
        elif self.action == "move":
            if self.direction not in (1, -1) or self.target != sign_colour(self.direction):
                raise ValueError(f"a move needs direction ±1 and the matching target: {self}")
        elif self.action == "press":
            if self.target not in ("red", "blue") or self.direction != colour_sign(self.target):
                raise ValueError(f"a press needs a target colour and its sign: {self}")
        else:
            raise ValueError(f"unknown arm action {self.action!r}")

    @classmethod
    def idle(cls, reason: str = "") -> ArmCommand:
        """No motion requested (the arm keeps its state)."""
        return cls("idle", 0, None, reason)

    @classmethod
    def stop(cls, reason: str = "") -> ArmCommand:
        """Bring the arm to rest and hold it there."""
        return cls("stop", 0, None, reason)

    @classmethod
    def move(cls, direction: int, reason: str = "") -> ArmCommand:
        """Move toward red (+1) or blue (−1)."""
        return cls("move", direction, sign_colour(direction), reason)

    @classmethod
    def press(cls, colour: Colour, reason: str = "") -> ArmCommand:
        """Go to a buzzer and press it."""
        return cls("press", colour_sign(colour), colour, reason)


class RobotBehaviour:
    """Algorithm 2 as a state machine over (t, z_r, human press, end-effector position)."""

    def __init__(
        self,
        layout: TableLayout,
        params: BehaviourParams | None = None,
        debounce: DebounceParams | None = None,
    ) -> None:
        """Create the machine for a table layout (needed to find the nearest buzzer)."""
        self.layout = layout
        self.params = params if params is not None else BehaviourParams()
        self.debounce = debounce if debounce is not None else DebounceParams()
        self.reset()

    def reset(self) -> None:
        """Forget the previous trial: back to idle, waiting for `start`."""
        self._phase: Phase = "idle"
        self._t_go: float | None = None
        self._timeout_s = math.inf
        self._t_last: float | None = None
        self._sign = SignDebouncer(self.debounce.c_max)  # the debounced direction of z_r
        self._pause_until = 0.0
        self._target: Colour | None = None
        self._last: ArmCommand = ArmCommand.idle("not started")

    # -- read-only state -------------------------------------------------------------------
    @property
    def phase(self) -> Phase:
        """The current phase name."""
        return self._phase

    @property
    def direction(self) -> int:
        """The debounced direction the robot follows: +1 red, −1 blue, 0 before its first move."""
        return self._sign.sign

    @property
    def t_go(self) -> float | None:
        """The time of "go" (s), or None before `start`."""
        return self._t_go

    @property
    def ended(self) -> bool:
        """True once the robot's choice is final (pressing, done)."""
        return self._phase in ("pressing", "done")

    @property
    def pressed_colour(self) -> Colour | None:
        """The buzzer the robot committed to press, or None if it has not committed."""
        return self._target

    # -- transitions -----------------------------------------------------------------------
    def start(self, t: float, timeout_s: float) -> ArmCommand:
        """The countdown said "go" at time t (s): wait for the first non-zero z_r.

        `timeout_s` is the trial's timeout after "go" (`ProtocolParams.trial_timeout_s`): if the
        human has not pressed by then, the robot presses the nearest buzzer.
        """
        if self._phase != "idle":
            raise RuntimeError(f"start() in phase {self._phase!r}; call reset() between trials")
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"timeout_s must be finite and > 0, got {timeout_s!r}")
        self._check_time(t)
        self._t_go = t
        self._timeout_s = timeout_s
        self._phase = "waiting"
        return self._emit(ArmCommand.idle("go: waiting for a non-zero z_r"))

    def complete(self) -> None:
        """The arm reports the press finished: pressing → done."""
        if self._phase == "pressing":
            self._phase = "done"

    def step(self, t: float, z_r: float | None, pressed: Colour | None, ee: Point) -> ArmCommand:
        """Advance to time t (s) with the latest inputs and return the command to apply.

        `z_r` is the robot's opinion (None when no new sample arrived; zero carries no sign and
        neither counts toward nor interrupts a reversal). `pressed` is the buzzer the human is
        pressing (`TableLayout.pressed` over the hand landmarks), None if neither. `ee` is the
        end effector in table coordinates, used to pick the nearest buzzer at the end.
        """
        self._check_time(t)
        if z_r is not None and not math.isfinite(z_r):
            raise ValueError(f"z_r must be finite, got {z_r!r}")
        phase = self._phase
        if phase == "idle":
            return self._emit(ArmCommand.idle("not started"))
        if phase in ("pressing", "done"):
            # Repeat the press so a driver that missed it (or a re-connected one) converges.
            return self._emit(self._last)

        assert self._t_go is not None  # set by start(), the only way out of idle
        if pressed is not None or t - self._t_go >= self._timeout_s:
            colour = self.layout.nearest(ee)
            self._target = colour
            self._phase = "pressing"
            why = f"human pressed {pressed}" if pressed is not None else "timeout"
            return self._emit(ArmCommand.press(colour, f"{why}: nearest buzzer is {colour}"))

        # None (no new sample) and 0 carry no sign: neither counts toward nor breaks a reversal.
        reversed_now = self._sign.feed(z_r) if z_r is not None else False
        if phase == "waiting":
            if self._sign.sign == 0:
                return self._emit(ArmCommand.idle("waiting for a non-zero z_r"))
            self._phase = "moving"
            return self._emit(ArmCommand.move(self._sign.sign, "first non-zero z_r"))

        if reversed_now:
            # Stop first: reversing at speed would whip the arm. Also entered from "pausing":
            # a flip back confirmed during the pause restarts the pause toward the new side.
            self._phase = "pausing"
            self._pause_until = t + self.params.pause_s
            return self._emit(ArmCommand.stop(f"z_r sign confirmed {self._sign.sign:+d}: pause"))
        if self._phase == "pausing":
            if t < self._pause_until:
                return self._emit(ArmCommand.stop("pausing before reversal"))
            self._phase = "moving"
            return self._emit(ArmCommand.move(self._sign.sign, "pause over"))
        return self._emit(ArmCommand.move(self._sign.sign, "continue"))

    # -- internals -------------------------------------------------------------------------
    def _check_time(self, t: float) -> None:
        if not math.isfinite(t):
            raise ValueError(f"time must be finite, got {t!r}")
        if self._t_last is not None and t < self._t_last:
            raise ValueError(f"time went backwards: {t} < {self._t_last}; pass monotonic time")
        self._t_last = t

    def _emit(self, cmd: ArmCommand) -> ArmCommand:
        self._last = cmd
        return cmd
