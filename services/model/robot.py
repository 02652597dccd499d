"""The robot's side of a trial: Algorithm 2 driven by the protocol's trial events.

One pure reactor that every runner of the robot uses — the actuation service on the fabric,
the offline closed loop, `nod analyze bstar` — so a trial's setup, "go", interruption and the
robot's press are handled in one place:

- `setup(trial, layout)`: a new trial; the previous one's moves and presses are forgotten, the
  layout (vision's latest) takes effect. The runner then sends the arm home.
- `go(t)`: Algorithm 2 starts (its timeout is the protocol's).
- `see_hand(landmarks)`: after "go", the first pose with a landmark inside a buzzer box is the
  human's press (what makes the robot press the buzzer nearest its end effector).
- `step(t, z_r, ee)`: one step of Algorithm 2 (None while no trial runs).
- `arm_pressed(colour)`: the arm reports a press; True exactly once per trial after "go" — the
  robot's choice, published (or recorded) once.
- `interrupted()`: the trial is void (a safe stop broke it): its moves are forgotten, so clearing
  the stop does not resume them.

Safety is not here: the runner's watchdog decides whether a command reaches the arm.
"""

from __future__ import annotations

from collections.abc import Sequence

from services.model.behaviour import ArmCommand, BehaviourParams, RobotBehaviour
from services.model.debounce import DebounceParams
from services.model.geometry import Colour, Point, TableLayout


class RobotTrial:
    """Algorithm 2 over a session's trials, one at a time."""

    def __init__(
        self,
        layout: TableLayout,
        behaviour: BehaviourParams,
        debounce: DebounceParams,
        timeout_s: float,
    ) -> None:
        """The robot for a table layout; `timeout_s` is the protocol's trial timeout."""
        self.behaviour_params = behaviour
        self.debounce = debounce
        self.timeout_s = timeout_s
        self.trial = 0
        self.layout = layout
        self.machine = RobotBehaviour(layout, behaviour, debounce)
        self.human: Colour | None = None  # the human's press this trial, as the robot saw it
        self.pressed: Colour | None = None  # the robot's own press this trial, once reported

    @property
    def running(self) -> bool:
        """Whether Algorithm 2 runs (from "go" until the trial is set up anew or voided)."""
        return self.machine.phase != "idle"

    def setup(self, trial: int, layout: TableLayout | None = None) -> None:
        """A new trial (`layout`: the geometry to use from now on)."""
        self.trial = trial
        if layout is not None:
            self.layout = layout
        self._forget()

    def go(self, t: float) -> ArmCommand:
        """The countdown said "go" at time t (s)."""
        return self.machine.start(t, self.timeout_s)

    def interrupted(self) -> None:
        """The trial is void: forget its moves (and any press seen)."""
        self._forget()

    def see_hand(self, landmarks: Sequence[Point]) -> Colour | None:
        """A hand pose after "go": the human's press, the first time a landmark is in a box."""
        if self.machine.t_go is not None and self.human is None:
            self.human = self.layout.pressed(landmarks)
        return self.human

    def step(self, t: float, z_r: float | None, ee: Point) -> ArmCommand | None:
        """One step of Algorithm 2 at time t with the latest z_r (None: no new sample)."""
        if not self.running:
            return None
        return self.machine.step(t, z_r, self.human, ee)

    def arm_pressed(self, colour: Colour) -> bool:
        """The arm pressed `colour`: True the first time this trial (after "go")."""
        if self.pressed is not None or self.machine.t_go is None:
            return False
        self.machine.complete()
        self.pressed = colour
        return True

    def _forget(self) -> None:
        self.machine = RobotBehaviour(self.layout, self.behaviour_params, self.debounce)
        self.human = None
        self.pressed = None
