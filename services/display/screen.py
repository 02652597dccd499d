"""What the participant's screen shows, from the conductor's events: a pure state machine.

The page (`services/display/static/`) only draws a `Screen`; every decision about what a
participant may see is made here, where it is tested:

- "wait" ("Please wait"): before the first trial, between a trial's end and its result, after an
  interruption or an aborted session, and whenever the conductor's liveliness is gone — never a
  stale "go";
- "ready" ("Get ready"): a trial was set up; the countdown follows;
- "countdown": the word being said ("1", "2", "3"), big;
- "go": "GO";
- "score": the trial's points and, when every earlier trial's result was seen, the total;
- "done": the session is over: "Thank you" and the total (kept when the conductor then exits).

Nothing that reveals the condition or the robot's opinion is shown: not the mode, the option O,
the gaze level (a setup's text), the robot's press or the outcome label — only the countdown,
go and points, the same for any number of options. The total is the sum of the scores of this
session's trials 1..n; a display that missed a result (started late, a resumed session) shows
the trial's points without a total rather than a wrong one.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Literal, TypeAlias

from services.core import messages as m

log = logging.getLogger("nod.display")
ScreenKind: TypeAlias = Literal["wait", "ready", "countdown", "go", "score", "done"]
MAX_WORD = 12  # a countdown word longer than this is not a word to show a participant


@dataclass(frozen=True, slots=True)
class Screen:
    """One screen of the page: its kind, a big line and a small line."""

    kind: ScreenKind
    big: str
    small: str = ""

    def as_json(self, version: int) -> dict[str, object]:
        """The page's payload (`version` orders updates; the page ignores older ones)."""
        return {"kind": self.kind, "big": self.big, "small": self.small, "version": version}


WAIT = Screen("wait", "Please wait")


def points(score: int) -> str:
    """A trial's points as a participant reads them: "+2 points", "0 points", "−1 point"."""
    sign = "+" if score > 0 else ("−" if score < 0 else "")
    unit = "point" if abs(score) == 1 else "points"
    return f"{sign}{abs(score)} {unit}"


@dataclass
class DisplayState:
    """Follows `experiment/trial`, `experiment/result` and the conductor's liveliness."""

    conductor_alive: bool = False
    session: str = ""
    screen: Screen = WAIT
    scores: dict[int, int] = field(default_factory=dict)  # this session's trial -> points
    version: int = 0  # bumped on every change of `screen`

    def total(self) -> int | None:
        """The session's total so far, if the results of trials 1..n (n ≥ 1) were all seen."""
        if not self.scores or set(self.scores) != set(range(1, len(self.scores) + 1)):
            return None
        return sum(self.scores.values())

    def _show(self, screen: Screen) -> bool:
        if screen == self.screen:
            return False
        self.screen = screen
        self.version += 1
        return True

    def on_conductor(self, alive: bool) -> bool:
        """The conductor's token came or went; True if the screen changed."""
        self.conductor_alive = alive
        if not alive and self.screen.kind != "done":  # what it showed is no longer true
            return self._show(WAIT)
        return False  # back: the next event says what to show

    def on_trial(self, ev: m.TrialEvent) -> bool:
        """A protocol event; True if the screen changed. Refuses what it cannot show honestly."""
        if ev.phase in ("setup", "countdown", "go", "end") and ev.trial < 1:
            raise ValueError(f"a {ev.phase} event for trial {ev.trial}: trials count from 1")
        if ev.session and ev.session != self.session:
            if ev.phase != "setup":  # joined mid-trial: not enough to show the countdown right
                log.info("display: session %s is new here; waiting for its next trial", ev.session)
            self.session, self.scores = ev.session, {}
            if ev.phase != "setup":
                return self._show(WAIT)
        if not self.conductor_alive:  # a late event of a conductor already gone
            return self._show(WAIT)
        if ev.phase == "setup":
            return self._show(Screen("ready", "Get ready"))
        if ev.phase == "countdown":
            word = ev.text.strip()
            if not word or len(word) > MAX_WORD:
                raise ValueError(f"countdown word {ev.text[:40]!r} is not 1-{MAX_WORD} characters")
            return self._show(Screen("countdown", word))
        if ev.phase == "go":
            return self._show(Screen("go", "GO"))
        if ev.phase == "session_end":
            total = self.total()
            return self._show(Screen("done", "Thank you", "" if total is None else
                                     f"Total: {points(total)}"))
        # end (the result follows), interrupted, abort, result: nothing to celebrate yet
        return self._show(WAIT)

    def on_result(self, res: m.TrialResult) -> bool:
        """A trial's result; True if the screen changed."""
        if res.trial < 1:
            raise ValueError(f"a result for trial {res.trial}: trials count from 1")
        if res.session != self.session:
            log.info("display: a result of session %s, not the current %s: ignored",
                     res.session or "(none)", self.session or "(none)")
            return False
        self.scores[res.trial] = 0 if res.interrupted else res.score
        if res.interrupted:  # never scored: no points to show
            return self._show(WAIT)
        if not self.conductor_alive:
            return self._show(WAIT)
        total = self.total()
        small = "" if total is None else f"Total: {points(total)}"
        return self._show(Screen("score", points(res.score), small))
