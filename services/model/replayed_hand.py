"""A recorded participant's hand, played back frame by frame into the offline loop.

Instead of the simulated `Participant`, the offline loop can be driven by the hand a real
session recorded: each trial's poses, timed from that trial's "go". At the loop's frame t of
trial k the hand is where it was (t − go) seconds after the recorded "go" of trial k (the
latest pose at or before then; before "go", the trial's first pose). It does not react to
anything — it is the recording — so the loop then runs the same decision model, robot and judge
over the same hand the live services saw, and the two give the same trials (a test holds them
equal, `tests/integration/test_record_replay.py`).
"""

from __future__ import annotations

import bisect
from collections.abc import Mapping, Sequence

import numpy as np

from services.model.geometry import Colour, Point

# One pose: seconds after the trial's recorded "go" (negative before it), its landmarks.
Pose = tuple[float, Sequence[Point]]


class ReplayedHand:
    """The `Participant` interface over recorded poses, one trial after another in order."""

    def __init__(self, trials: Mapping[int, Sequence[Pose]]) -> None:
        """`trials`: per trial index, its detected poses in time order (at least one each)."""
        self._trials = {k: list(v) for k, v in trials.items() if v}
        self._order = sorted(self._trials)
        self._next = 0
        self._poses: list[Pose] = []
        self._times: list[float] = []
        self._t_go: float | None = None
        self._now = 0.0
        self.pressed: Colour | None = None  # unused: the judge reads the press from the poses

    def new_trial(self, option: object) -> None:
        """The next recorded trial begins ("setup")."""
        if self._next >= len(self._order):
            raise ValueError(f"the recording has only {len(self._order)} trial(s) with poses")
        self._poses = self._trials[self._order[self._next]]
        self._times = [t for t, _ in self._poses]
        self._next += 1
        self._t_go = None

    def go(self, t: float) -> None:
        """The loop's "go": the recorded path starts here."""
        self._t_go = t

    def advance(self, t: float) -> None:
        """Move to loop time t."""
        self._now = t

    def landmarks(self) -> np.ndarray:
        """The recorded pose at the loop's current time."""
        rel = -np.inf if self._t_go is None else self._now - self._t_go
        i = max(0, bisect.bisect_right(self._times, rel) - 1)
        return np.asarray(self._poses[i][1], dtype=float)

    def unseen(self) -> None:
        """A frame whose pose nobody reads: nothing to do (`Participant.unseen`)."""

    # What a participant perceives: a recording perceives nothing.
    def see_gaze(self, gaze: object) -> None:
        """Ignored: the recording already contains whatever the gaze did."""

    def see_robot(self, t: float, heading: int | None) -> None:
        """Ignored: the recording already contains whatever the robot did."""

    def trial_ended(self, robot: object) -> None:
        """Ignored: nothing to learn."""
