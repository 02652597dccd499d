"""The robot's press of a trial, as the conductor takes it: only when the arm's state confirms it.

A press on the press key alone could be anyone's (a forged message, a second actuation), so
it counts once an arm state of the same trial shows the arm done pressing that box: the latest
state, or one of the next (a state may be dropped on a busy link). A normal press arrives a
little before the state that confirms it, so waiting is the usual path, not an anomaly; a press
still unconfirmed when the trial ends is refused and reported.

A box is what the session's messages name it by (`services.experiment.keyspace.Wire`): a colour
on the paper's keys, an index on a table of N boxes; the rule is the same.
"""

from __future__ import annotations

Box = str | int  # a colour (the paper's keys) or a box index (N boxes)


class RobotPresses:
    """The current trial's robot press, confirmed by the arm's own state."""

    def __init__(self) -> None:
        self.trial = 0
        self.confirmed: Box | None = None
        self._pending: dict[Box, int] = {}  # unconfirmed presses: box -> trial
        self._arm: tuple[int, str, Box | None] = (0, "idle", None)  # trial, phase, target
        self.refused = 0  # presses never confirmed, over the session

    def begin(self, trial: int) -> None:
        """A trial is set up: its press is still to come."""
        self.trial = trial
        self.confirmed = None
        self._pending = {}

    def arm_state(self, trial: int, phase: str, target: Box | None) -> None:
        """An arm state: it may confirm a press already received."""
        self._arm = (trial, phase, target)
        if self.confirmed is None:
            for box, press_trial in self._pending.items():
                if self._confirms(press_trial, box):
                    self.confirmed = box
                    break

    def press(self, trial: int, box: Box) -> None:
        """A press of `box` in `trial`: taken if the arm's latest state confirms it, else kept."""
        if trial != self.trial or self.confirmed is not None:
            return
        if self._confirms(trial, box):
            self.confirmed = box
        else:
            self._pending.setdefault(box, trial)

    def unconfirmed(self) -> list[Box]:
        """At the trial's end: the boxes pressed on the key that the arm never confirmed."""
        refused = [c for c in self._pending if c != self.confirmed]
        self.refused += len(refused)
        self._pending = {}
        return refused

    def where(self) -> tuple[int, str, Box | None]:
        """The arm's latest state: (trial, phase, target)."""
        return self._arm

    def _confirms(self, press_trial: int, box: Box) -> bool:
        trial, phase, target = self._arm
        # "done": the arm has finished pressing (a forged press while it is still on its way to
        # that box must not end the trial early).
        return trial == press_trial and phase == "done" and target == box
