"""The robot's behaviour during one trial: paper Algorithm 2 as the prose of SPEC §4, N ≥ 2 boxes.

The pseudo-code in the paper is garbled (its last branch turns red whenever σ ≠ 0), so this
state machine implements the prose instead:

- after "go", start moving toward z_r's leading option (with two, sgn(z_r)) once it has one;
- a change of heading needs C_max consecutive samples leading the same new option (the
  debounce that counts the human's switches, `services.model.debounce`); then stop, pause
  `pause_s`, and move toward the new box. A shorter change is ignored, an interrupted one
  resets the count; a sample with no leading option (a zero z_r, a tie) neither counts toward
  nor breaks a change;
- when the human pressed (a hand landmark inside a box) or the trial timed out, stop at once and
  press the box nearest the end effector (`nearest` of the layout). The timeout is the
  protocol's (`ProtocolParams.trial_timeout_s`), passed to `start`: a trial has one timeout.

Phases: idle → waiting (after `start`) → moving ⇄ pausing → pressing → done. Safety is not a
phase: the actuation shell's watchdog holds the arm and the machine resumes when it clears. The
machine is pure: time is an argument in seconds (float, any monotonic origin, typically sim or
message time), and it never touches hardware — it returns a command that a driver applies.

The machine (`Algorithm2`) is written once over option indices. What differs by N is how a
sample of z_r names its leading option and the vocabulary of the commands:
`OptionsBehaviour` is the general form (z_r a vector, boxes by index, `OptionsCommand`, the
dissensus tie rule `leader_or_nearest_tie` on request); `RobotBehaviour` is its two-option
kernel, the paper's (z_r a number whose sign leads, red and blue, `ArmCommand`), kept because
the paper's rig speaks in colours and signs. On the paper's table the two give the same commands
and phases (tests/unit/test_behaviour.py, hypothesis).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Generic, Literal, TypeAlias, TypeVar

import numpy as np

from services.model.debounce import DebounceParams, LeaderDebouncer, option_sign, sign_option
from services.model.dynamics import leading_option
from services.model.geometry import (
    TIE,
    Colour,
    OptionsLayout,
    Point,
    TableLayout,
    colour_sign,
    sign_colour,
)

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
    """One command for the arm on the paper's table.

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


@dataclass(frozen=True, slots=True)
class OptionsCommand:
    """One arm command over N boxes: idle, stop, move toward box `target`, or press it."""

    action: Action
    target: int | None = None
    reason: str = ""

    def __post_init__(self) -> None:
        if self.action not in ("idle", "stop", "move", "press"):
            raise ValueError(f"unknown arm action {self.action!r}")
        if (self.action in ("move", "press")) != (self.target is not None):
            raise ValueError(f"a move or a press needs a target box, idle and stop none: {self}")


# Opinions within this of z_r's largest are tied for it (`leader_or_nearest_tie`): an exact tie
# among the options other than the human's, which the dynamics keep by symmetry, comes out of
# the integrator ~1e-16 apart (the last option is minus the sum of the others), and those ulps
# must not pick the robot's box. Opinions are O(0.1-1), so 1e-9 is far above the rounding and
# far below any real lead.
TIE_TOLERANCE = 1e-9


def leader_or_nearest_tie(
    z: np.ndarray, layout: OptionsLayout, ee: Point, tol: float = TIE_TOLERANCE
) -> int | None:
    """The leading option of z; when several but not all tie for the top, the nearest of them.

    The tie rule of a dissensus robot (docs/multi-option.md): with the controller off and the
    human on h, γ < 0 raises every other option equally, so z_r ties among them; the robot
    follows the tied box nearest its end effector (a tie in distance to the lower index, as
    `OptionsLayout.nearest`). Once it moves there that box gets nearer, so the choice holds.
    All options tied (z = 0) is no leader, as a zero z_r carries no sign; with two options a
    tie is always that, so two boxes read exactly as `leading_option` outside ±tol.
    """
    flat = np.asarray(z, dtype=float)
    top = float(flat.max())
    tied = [j for j in range(flat.size) if flat[j] >= top - tol]
    if len(tied) == 1:
        return tied[0]
    if len(tied) == flat.size:
        return None
    best, best_d = tied[0], math.dist(ee, layout.boxes[tied[0]].center)
    for j in tied[1:]:
        d = math.dist(ee, layout.boxes[j].center)
        if d < best_d - TIE:
            best, best_d = j, d
    return best


Layout = TypeVar("Layout", TableLayout, OptionsLayout)
Command = TypeVar("Command", ArmCommand, OptionsCommand)
Box = TypeVar("Box")
Z = TypeVar("Z")


class Algorithm2(ABC, Generic[Layout, Command, Box, Z]):
    """Algorithm 2 as a state machine over (t, z_r, human press, end effector), any N boxes.

    Subclasses say how a sample of z_r names its leading option (`_lead`) and how a command
    is spelled (`_idle`, `_stop`, `_move`, `_press`, and the reasons' words); the phases, the
    debounce, the pause and the press are here, once.
    """

    # The words of the reasons (logs only): what "waiting for …" waits for, the first move's
    # cause, and the stop of a pause.
    _awaited = "a leading option"
    _first_lead = "first leading option"
    _pausing = "pausing before turning"

    def __init__(
        self,
        layout: Layout,
        params: BehaviourParams | None = None,
        debounce: DebounceParams | None = None,
    ) -> None:
        """Create the machine for a table layout (needed to find the nearest box)."""
        self.layout: Layout = layout
        self.params = params if params is not None else BehaviourParams()
        self.debounce = debounce if debounce is not None else DebounceParams()
        self.reset()

    # -- what differs by N -----------------------------------------------------------------
    @abstractmethod
    def _lead(self, z_r: Z, ee: Point) -> int | None:
        """The option a (finite) sample of z_r leads with, None for none; raises if not finite."""

    @abstractmethod
    def _idle(self, reason: str) -> Command:
        """No motion requested."""

    @abstractmethod
    def _stop(self, reason: str) -> Command:
        """Bring the arm to rest."""

    @abstractmethod
    def _move(self, option: int, reason: str) -> Command:
        """Head for the box of `option`."""

    @abstractmethod
    def _press(self, box: Box, why: str) -> Command:
        """Press `box` (the nearest), because of `why` (the human's press, the timeout)."""

    @abstractmethod
    def _nearest(self, ee: Point) -> Box:
        """The box nearest the end effector on `self.layout`."""

    @abstractmethod
    def _confirmed(self, option: int) -> str:
        """The reason of the stop that confirms a change of heading to `option`."""

    def reset(self) -> None:
        """Forget the previous trial: back to idle, waiting for `start`."""
        self._phase: Phase = "idle"
        self._t_go: float | None = None
        self._timeout_s = math.inf
        self._t_last: float | None = None
        self._leader = LeaderDebouncer(self.debounce.c_max)  # the debounced heading
        self._pause_until = 0.0
        self._target: Box | None = None
        self._last: Command = self._idle("not started")

    # -- read-only state -------------------------------------------------------------------
    @property
    def phase(self) -> Phase:
        """The current phase name."""
        return self._phase

    @property
    def heading(self) -> int | None:
        """The debounced option the robot follows (None before its first move)."""
        return self._leader.leader

    @property
    def t_go(self) -> float | None:
        """The time of "go" (s), or None before `start`."""
        return self._t_go

    @property
    def ended(self) -> bool:
        """True once the robot's choice is final (pressing, done)."""
        return self._phase in ("pressing", "done")

    # -- transitions -----------------------------------------------------------------------
    def start(self, t: float, timeout_s: float) -> Command:
        """The countdown said "go" at time t (s): wait for z_r's first leading option.

        `timeout_s` is the trial's timeout after "go" (`ProtocolParams.trial_timeout_s`): if the
        human has not pressed by then, the robot presses the nearest box.
        """
        if self._phase != "idle":
            raise RuntimeError(f"start() in phase {self._phase!r}; call reset() between trials")
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"timeout_s must be finite and > 0, got {timeout_s!r}")
        self._check_time(t)
        self._t_go, self._timeout_s, self._phase = t, timeout_s, "waiting"
        return self._emit(self._idle(f"go: waiting for {self._awaited}"))

    def complete(self) -> None:
        """The arm reports the press finished: pressing → done."""
        if self._phase == "pressing":
            self._phase = "done"

    def step(self, t: float, z_r: Z | None, pressed: Box | None, ee: Point) -> Command:
        """Advance to time t (s) with the latest inputs and return the command to apply.

        `z_r` is the robot's opinion (None when no new sample arrived). `pressed` is the box
        the human is pressing (the layout's `pressed` over the hand landmarks), None if none.
        `ee` is the end effector in table coordinates, used to pick the nearest box at the end
        (and, with the tie rule, the nearest of tied options).
        """
        self._check_time(t)
        lead = self._lead(z_r, ee) if z_r is not None else None  # validates z_r in any phase
        phase = self._phase
        if phase == "idle":
            return self._emit(self._idle("not started"))
        if phase in ("pressing", "done"):
            # Repeat the press so a driver that missed it (or a re-connected one) converges.
            return self._emit(self._last)

        assert self._t_go is not None  # set by start(), the only way out of idle
        if pressed is not None or t - self._t_go >= self._timeout_s:
            box = self._nearest(ee)
            self._target, self._phase = box, "pressing"
            why = f"human pressed {pressed}" if pressed is not None else "timeout"
            return self._emit(self._press(box, why))

        # No new sample, and one with no leading option, neither count toward nor break a change.
        changed = self._leader.feed_leader(lead) if z_r is not None else False
        leader = self._leader.leader
        if phase == "waiting":
            if leader is None:
                return self._emit(self._idle(f"waiting for {self._awaited}"))
            self._phase = "moving"
            return self._emit(self._move(leader, self._first_lead))

        assert leader is not None  # set before leaving "waiting"
        if changed:
            # Stop first: reversing at speed would whip the arm. Also entered from "pausing":
            # a change back confirmed during the pause restarts the pause toward the new box.
            self._phase = "pausing"
            self._pause_until = t + self.params.pause_s
            return self._emit(self._stop(self._confirmed(leader)))
        if phase == "pausing":
            if t < self._pause_until:
                return self._emit(self._stop(self._pausing))
            self._phase = "moving"
            return self._emit(self._move(leader, "pause over"))
        return self._emit(self._move(leader, "continue"))

    # -- internals -------------------------------------------------------------------------
    def _check_time(self, t: float) -> None:
        if not math.isfinite(t):
            raise ValueError(f"time must be finite, got {t!r}")
        if self._t_last is not None and t < self._t_last:
            raise ValueError(f"time went backwards: {t} < {self._t_last}; pass monotonic time")
        self._t_last = t

    def _emit(self, cmd: Command) -> Command:
        self._last = cmd
        return cmd


class RobotBehaviour(Algorithm2[TableLayout, ArmCommand, Colour, float]):
    """The paper's Algorithm 2 (the two-option kernel): z_r a number, red (+) and blue (−)."""

    _awaited = "a non-zero z_r"
    _first_lead = "first non-zero z_r"
    _pausing = "pausing before reversal"

    @property
    def direction(self) -> int:
        """The debounced direction the robot follows: +1 red, −1 blue, 0 before its first move."""
        return option_sign(self.heading)

    @property
    def pressed_colour(self) -> Colour | None:
        """The buzzer the robot committed to press, or None if it has not committed."""
        return self._target

    def _lead(self, z_r: float, ee: Point) -> int | None:
        # A zero z_r carries no sign: it neither counts toward nor interrupts a reversal.
        if not math.isfinite(z_r):
            raise ValueError(f"z_r must be finite, got {z_r!r}")
        return sign_option(z_r)

    def _idle(self, reason: str) -> ArmCommand:
        return ArmCommand.idle(reason)

    def _stop(self, reason: str) -> ArmCommand:
        return ArmCommand.stop(reason)

    def _move(self, option: int, reason: str) -> ArmCommand:
        return ArmCommand.move(option_sign(option), reason)

    def _press(self, box: Colour, why: str) -> ArmCommand:
        return ArmCommand.press(box, f"{why}: nearest buzzer is {box}")

    def _nearest(self, ee: Point) -> Colour:
        return self.layout.nearest(ee)

    def _confirmed(self, option: int) -> str:
        return f"z_r sign confirmed {option_sign(option):+d}: pause"


class OptionsBehaviour(Algorithm2[OptionsLayout, OptionsCommand, int, np.ndarray]):
    """Algorithm 2 over N boxes (the general form): z_r a vector, boxes by index."""

    def __init__(
        self,
        layout: OptionsLayout,
        params: BehaviourParams | None = None,
        debounce: DebounceParams | None = None,
        break_ties: bool = False,
    ) -> None:
        """Create the machine for a table of N boxes (needed to find the nearest one).

        `break_ties`: a tie for z_r's largest among some options leads with the nearest of
        them (`leader_or_nearest_tie`); off, a tie carries no option (`leading_option`).
        """
        self.break_ties = break_ties
        super().__init__(layout, params, debounce)

    @property
    def pressed_option(self) -> int | None:
        """The box the robot committed to press, or None."""
        return self._target

    def _lead(self, z_r: np.ndarray, ee: Point) -> int | None:
        if not np.all(np.isfinite(z_r)):
            raise ValueError(f"z_r must be finite, got {z_r!r}")
        if self.break_ties:
            return leader_or_nearest_tie(z_r, self.layout, ee)
        return leading_option(z_r)

    def _idle(self, reason: str) -> OptionsCommand:
        return OptionsCommand("idle", reason=reason)

    def _stop(self, reason: str) -> OptionsCommand:
        return OptionsCommand("stop", reason=reason)

    def _move(self, option: int, reason: str) -> OptionsCommand:
        return OptionsCommand("move", option, reason)

    def _press(self, box: int, why: str) -> OptionsCommand:
        return OptionsCommand("press", box, f"{why}: nearest box is {box}")

    def _nearest(self, ee: Point) -> int:
        return self.layout.nearest(ee)

    def _confirmed(self, option: int) -> str:
        return f"leader confirmed {option}: pause"
