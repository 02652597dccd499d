"""The robot's side of a trial: Algorithm 2 driven by the protocol's trial events, N ≥ 2 boxes.

One pure reactor that every runner of the robot uses — the actuation services on the fabric,
the offline closed loops, `nod analyze bstar` — so a trial's setup, "go", interruption and the
robot's press are handled in one place:

- `setup(trial, layout)`: a new trial; the previous one's moves and presses are forgotten, the
  layout (vision's latest) takes effect. The runner then sends the arm home.
- `go(t)`: Algorithm 2 starts (its timeout is the protocol's).
- `see_hand(landmarks)`: after "go", the first pose with a landmark inside a box is the
  human's press (what makes the robot press the box nearest its end effector).
- `step(t, z_r, ee)`: one step of Algorithm 2 (None while no trial runs).
- `arm_pressed(box)`: the arm reports a press; True exactly once per trial after "go" — the
  robot's choice, published (or recorded) once.
- `interrupted()`: the trial is void (a safe stop broke it): its moves are forgotten, so clearing
  the stop does not resume them.

The reactor (`TrialReactor`) is written once for any number of boxes; what it drives is
Algorithm 2's machine for the table. `OptionsRobotTrial` is the general form: N boxes named by
index, z_r a vector, `OptionsBehaviour` with the dissensus tie rule (a robot tied among the
options other than the human's follows the nearest of them, docs/multi-option.md).
`RobotTrial` is its two-option kernel, the paper's: red and blue, z_r a number,
`RobotBehaviour`. On the paper's table they give the same commands and phases (tests/unit/
test_reactors.py, hypothesis).

Safety is not here: the runner's watchdog decides whether a command reaches the arm.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterable, Sequence
from typing import Generic, Protocol, TypeVar

import numpy as np

from services.model.behaviour import (
    ArmCommand,
    BehaviourParams,
    OptionsBehaviour,
    OptionsCommand,
    RobotBehaviour,
)
from services.model.debounce import DebounceParams
from services.model.geometry import Colour, OptionsLayout, Point, TableLayout

Command_co = TypeVar("Command_co", covariant=True)
Box_contra = TypeVar("Box_contra", contravariant=True)
Z_contra = TypeVar("Z_contra", contravariant=True)
Command = TypeVar("Command")
Box = TypeVar("Box")
Z = TypeVar("Z")
Layout = TypeVar("Layout", TableLayout, OptionsLayout)


class Machine(Protocol[Command_co, Box_contra, Z_contra]):
    """Algorithm 2 for one trial as the reactor drives it (`RobotBehaviour`, `OptionsBehaviour`)."""

    @property
    def phase(self) -> str:
        """Idle until `start`, never again after it."""

    @property
    def ended(self) -> bool:
        """True once the choice is final: each step repeats the press, whatever z_r."""

    def start(self, t: float, timeout_s: float) -> Command_co:
        """The countdown said "go" at time t (s)."""

    def step(
        self, t: float, z_r: Z_contra | None, pressed: Box_contra | None, ee: Point
    ) -> Command_co:
        """One step with the latest z_r (None: no new sample) and the human's press."""

    def complete(self) -> None:
        """The arm reported the press."""


class TrialReactor(ABC, Generic[Layout, Command, Box, Z]):
    """Algorithm 2 over a session's trials, one at a time, for any number of boxes."""

    def __init__(
        self,
        layout: Layout,
        behaviour: BehaviourParams,
        debounce: DebounceParams,
        timeout_s: float,
    ) -> None:
        """The robot for a table layout; `timeout_s` is the protocol's trial timeout."""
        self.behaviour_params = behaviour
        self.debounce = debounce
        self.timeout_s = timeout_s
        self.trial = 0
        self.layout: Layout = layout
        self.machine = self._machine()
        self.human: Box | None = None  # the human's press this trial, as the robot saw it
        self.pressed: Box | None = None  # the robot's own press this trial, once reported

    @abstractmethod
    def _machine(self) -> Machine[Command, Box, Z]:
        """A fresh Algorithm 2 for `self.layout`."""

    @abstractmethod
    def _pressed(self, landmarks: Iterable[Point]) -> Box | None:
        """The box holding any of the landmarks on `self.layout`, or None."""

    @property
    def running(self) -> bool:
        """Whether Algorithm 2 runs (from "go" until the trial is set up anew or voided)."""
        return self.machine.phase != "idle"

    @property
    def decided(self) -> bool:
        """Whether this trial's choice is final (pressing or pressed: z_r no longer counts)."""
        return self.machine.ended

    def setup(self, trial: int, layout: Layout | None = None) -> None:
        """A new trial (`layout`: the geometry to use from now on)."""
        self.trial = trial
        if layout is not None:
            self.layout = layout
        self._forget()

    def go(self, t: float) -> Command:
        """The countdown said "go" at time t (s)."""
        return self.machine.start(t, self.timeout_s)

    def interrupted(self) -> None:
        """The trial is void: forget its moves (and any press seen)."""
        self._forget()

    def see_hand(self, landmarks: Sequence[Point]) -> Box | None:
        """A hand pose after "go": the human's press, the first time a landmark is in a box."""
        if self.running and self.human is None:
            self.human = self._pressed(landmarks)
        return self.human

    def step(self, t: float, z_r: Z | None, ee: Point) -> Command | None:
        """One step of Algorithm 2 at time t with the latest z_r (None: no new sample)."""
        if not self.running:
            return None
        return self.machine.step(t, z_r, self.human, ee)

    def arm_pressed(self, box: Box) -> bool:
        """The arm pressed `box`: True the first time this trial (after "go")."""
        if self.pressed is not None or not self.running:
            return False
        self.machine.complete()
        self.pressed = box
        return True

    def _forget(self) -> None:
        self.machine = self._machine()
        self.human = None
        self.pressed = None


class RobotTrial(TrialReactor[TableLayout, ArmCommand, Colour, float]):
    """The paper's robot (the two-option kernel): red and blue, z_r a number."""

    machine: RobotBehaviour

    def _machine(self) -> RobotBehaviour:
        return RobotBehaviour(self.layout, self.behaviour_params, self.debounce)

    def _pressed(self, landmarks: Iterable[Point]) -> Colour | None:
        return self.layout.pressed(landmarks)


class OptionsRobotTrial(TrialReactor[OptionsLayout, OptionsCommand, int, np.ndarray]):
    """The robot over N boxes (the general form): option indices, z_r a vector, the tie rule."""

    machine: OptionsBehaviour

    def _machine(self) -> OptionsBehaviour:
        return OptionsBehaviour(self.layout, self.behaviour_params, self.debounce, break_ties=True)

    def _pressed(self, landmarks: Iterable[Point]) -> int | None:
        return self.layout.pressed(landmarks)
