"""The participant's cues as played (`speaker/played`), kept until their trial is stored.

The conductor files each onset under the trial and attempt it belongs to and hands the pending
ones to the store's transaction that writes that trial or its interruption (`Store.write_trial`,
`Store.write_interruption`): a trial and its cues are on record together or not at all. An
onset that arrives after its trial was stored (a late speaker) goes with the next write, still
under its own trial. The speaker is not required: a trial without it simply has no cues.
"""

from __future__ import annotations

from services.core import messages as m
from services.store import CueRecord

MAX_PENDING = 256  # far beyond the 4 cues of a trial: a flood from a bad peer is capped


class CueLog:
    """Pending cue onsets (under the node lock, like every callback)."""

    def __init__(self) -> None:
        self.trial = 0
        self.attempt = 0
        self._pending: list[CueRecord] = []

    def begin(self, trial: int, attempt: int) -> None:
        """A trial's attempt starts: its cues are filed under it."""
        self.trial, self.attempt = trial, attempt

    def on_played(self, msg: m.CuePlayed) -> None:
        """A cue's onset from the speaker."""
        if len(self._pending) >= MAX_PENDING:
            return
        attempt = self.attempt if msg.trial == self.trial else 0  # 0: not of the current trial
        self._pending.append(
            CueRecord(msg.trial, attempt, msg.cue, msg.planned_ns, msg.played_ns)
        )

    def take(self) -> list[CueRecord]:
        """The pending cues, handed to the store's next write."""
        cues, self._pending = self._pending, []
        return cues
