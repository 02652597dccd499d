"""The robot's press of a trial, as the conductor takes it: only when the arm's state confirms it.

A press on `actuation/press` alone could be anyone's (a forged message, a second actuation), so
it counts once an `actuation/state` of the same trial shows the arm done pressing that buzzer:
the latest state, or one of the next (a state may be dropped on a busy link). A normal press
arrives a little before the state that confirms it, so waiting is the usual path, not an
anomaly; a press still unconfirmed when the trial ends is refused and reported.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from services.model.geometry import Colour

if TYPE_CHECKING:  # decoded messages only; no codec needed
    from services.core import messages as m


class RobotPresses:
    """The current trial's robot press, confirmed by the arm's own state."""

    def __init__(self) -> None:
        self.trial = 0
        self.confirmed: Colour | None = None
        self._pending: dict[str, m.PressMsg] = {}  # unconfirmed presses, per colour
        self._arm: tuple[int, str, str | None] = (0, "idle", None)  # trial, phase, target
        self.refused = 0  # presses never confirmed, over the session

    def begin(self, trial: int) -> None:
        """A trial is set up: its press is still to come."""
        self.trial = trial
        self.confirmed = None
        self._pending = {}

    def arm_state(self, trial: int, phase: str, target: str | None) -> None:
        """An actuation/state: it may confirm a press already received."""
        self._arm = (trial, phase, target)
        if self.confirmed is None:
            for press in self._pending.values():
                if self._confirms(press):
                    self.confirmed = press.colour
                    break

    def press(self, msg: m.PressMsg) -> None:
        """An actuation/press: taken now if the arm's latest state confirms it, else kept."""
        if msg.trial != self.trial or self.confirmed is not None:
            return
        if self._confirms(msg):
            self.confirmed = msg.colour
        else:
            self._pending.setdefault(msg.colour, msg)

    def unconfirmed(self) -> list[str]:
        """At the trial's end: the colours pressed on the key that the arm never confirmed."""
        refused = [c for c in self._pending if c != self.confirmed]
        self.refused += len(refused)
        self._pending = {}
        return refused

    def where(self) -> tuple[int, str, str | None]:
        """The arm's latest state: (trial, phase, target)."""
        return self._arm

    def _confirms(self, press: m.PressMsg) -> bool:
        trial, phase, target = self._arm
        # "done": the arm has finished pressing (a forged press while it is still on its way to
        # that buzzer must not end the trial early).
        return trial == press.trial and phase == "done" and target == press.colour
