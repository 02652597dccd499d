"""The robot's side of an N_o-option trial: `RobotTrial` over N_o boxes.

The same reactor as `services.model.robot.RobotTrial` — setup, "go", the human's press seen
in the poses, one step of Algorithm 2, the arm's press reported once, a voided trial forgotten
— with `OptionsBehaviour` (the tie rule on: a dissensus robot tied among the options other
than the human's follows the nearest of them, docs/multi-option.md) and option indices.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from services.model.behaviour import BehaviourParams
from services.model.debounce import DebounceParams
from services.model.geometry import Point
from services.model.options_behaviour import OptionsBehaviour, OptionsCommand
from services.model.options_geometry import OptionsLayout


class OptionsRobotTrial:
    """Algorithm 2 over a session's trials on N_o boxes, one at a time."""

    def __init__(
        self,
        layout: OptionsLayout,
        behaviour: BehaviourParams,
        debounce: DebounceParams,
        timeout_s: float,
    ) -> None:
        """The robot for a table of N_o boxes; `timeout_s` is the protocol's trial timeout."""
        self.behaviour_params = behaviour
        self.debounce = debounce
        self.timeout_s = timeout_s
        self.trial = 0
        self.layout = layout
        self.machine = self._machine()
        self.human: int | None = None  # the human's press this trial, as the robot saw it
        self.pressed: int | None = None  # the robot's own press this trial, once reported

    @property
    def running(self) -> bool:
        """Whether Algorithm 2 runs (from "go" until the trial is set up anew or voided)."""
        return self.machine.phase != "idle"

    def setup(self, trial: int, layout: OptionsLayout | None = None) -> None:
        """A new trial (`layout`: the geometry to use from now on)."""
        self.trial = trial
        if layout is not None:
            self.layout = layout
        self._forget()

    def go(self, t: float) -> OptionsCommand:
        """The countdown said "go" at time t (s)."""
        return self.machine.start(t, self.timeout_s)

    def interrupted(self) -> None:
        """The trial is void: forget its moves (and any press seen)."""
        self._forget()

    def see_hand(self, landmarks: Sequence[Point]) -> int | None:
        """A hand pose after "go": the human's press, the first time a landmark is in a box."""
        if self.running and self.human is None:
            self.human = self.layout.pressed(landmarks)
        return self.human

    def step(self, t: float, z_r: np.ndarray | None, ee: Point) -> OptionsCommand | None:
        """One step of Algorithm 2 at time t with the latest z_r (None: no new sample)."""
        if not self.running:
            return None
        return self.machine.step(t, z_r, self.human, ee)

    def arm_pressed(self, option: int) -> bool:
        """The arm pressed box `option`: True the first time this trial (after "go")."""
        if self.pressed is not None or not self.running:
            return False
        self.machine.complete()
        self.pressed = option
        return True

    def _machine(self) -> OptionsBehaviour:
        return OptionsBehaviour(self.layout, self.behaviour_params, self.debounce, break_ties=True)

    def _forget(self) -> None:
        self.machine = self._machine()
        self.human = None
        self.pressed = None
