"""Outcomes of an N_o-option trial: switches of the human's leading option, C/CH/D/DH, points.

SPEC §6 over N_o options (docs/multi-option.md):

- *switches*: changes of ẑ_h's leading option, debounced like Algorithm 2 (`LeaderDebouncer`
  with the session's C_max). A sample whose lead over the runner-up is within the dead band
  (half the lead ≤ `switch_dead_band`, which is |ẑ_h| ≤ dead band with two boxes) carries no
  option, as a zero ẑ_h carries no sign;
- *violations*: every switch after the first, and every one that began at or after the sample
  where the hand crossed the commit line (`OutcomeTracker`'s rules);
- *outcome*: C / CH / D / DH from the switches and whether both pressed the same box; control
  trials by agreement alone unless `control_labels = "switches"`; the score is SPEC §6's
  (`score_trial`).

`OptionsTrialJudge` is the conductor-side reactor, as `services.model.judge.TrialJudge`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from services.model.debounce import LeaderDebouncer
from services.model.dynamics import leading_option
from services.model.geometry import CommitLine, OptionsLayout, Point
from services.model.outcome import Outcome
from services.model.params import NodConfig
from services.model.protocol import Mode, TrialEnd
from services.model.scoring import score_trial


def human_lead(z_hat: np.ndarray, dead_band: float) -> int | None:
    """ẑ_h's leading option, None when its half-lead over the runner-up is within the band."""
    top_two = np.sort(np.asarray(z_hat, dtype=float))[-2:]
    if 0.5 * float(top_two[1] - top_two[0]) <= dead_band:
        return None
    return leading_option(z_hat)


class OptionsOutcomeTracker:
    """Switches and violations of one trial from its ẑ_h vectors and hand centres."""

    def __init__(self, c_max: int, commit: CommitLine, dead_band: float) -> None:
        """Debounce with `c_max`; crossings against `commit`; `dead_band` as above."""
        self.commit = commit
        self.dead_band = dead_band
        self._lead = LeaderDebouncer(c_max)
        self._onsets: list[int] = []
        self._crossed_at: int | None = None
        self._n = 0

    @property
    def switches(self) -> int:
        """Switches confirmed so far."""
        return len(self._onsets)

    @property
    def first(self) -> int | None:
        """The first option ẑ_h led with (None if it never led)."""
        return self._lead.first

    @property
    def violations(self) -> int:
        """Every switch after the first, and every late one (SPEC §6)."""
        crossed = self._crossed_at
        return sum(
            1 for k, onset in enumerate(self._onsets)
            if k >= 1 or (crossed is not None and onset >= crossed)
        )

    def add(self, z_hat: np.ndarray, center: Point | None) -> None:
        """One observation: ẑ_h and the hand centre (None when no hand was detected)."""
        if not np.all(np.isfinite(z_hat)):
            raise ValueError(f"z_hat must be finite, got {z_hat!r}")
        if self._crossed_at is None and center is not None and self.commit.crossed(center):
            self._crossed_at = self._n
        self._n += 1
        if self._lead.feed_leader(human_lead(z_hat, self.dead_band)):
            self._onsets.append(self._lead.onset)


@dataclass(frozen=True, slots=True)
class OptionsJudgement:
    """What is stored for a finished N_o-option trial (options as indices)."""

    human: int | None  # None: the human never pressed (timeout)
    robot: int | None  # None: the robot did not press
    outcome: Outcome | None  # None unless both pressed
    switches: int
    violations: int
    score: int


def classify(switches: int, same: bool) -> Outcome:
    """C / CH / D / DH from the number of switches and whether both pressed the same box."""
    if switches == 0:
        return "C" if same else "D"
    return "CH" if same else "DH"


class OptionsTrialJudge:
    """Judges one N_o-option trial from its "go" (`services.model.judge.TrialJudge`'s rules)."""

    def __init__(self, cfg: NodConfig, layout: OptionsLayout, mode: Mode = "consensus") -> None:
        """A judge for a `mode` trial on `layout`, with the session's debounce and labels."""
        self.layout = layout
        self.by_agreement = mode == "dissensus" and cfg.protocol.control_labels == "agreement"
        self.target_clicks = cfg.protocol.target_clicks
        self.tracker = OptionsOutcomeTracker(
            cfg.debounce.c_max, cfg.layout.commit, cfg.decision.observer.switch_dead_band
        )
        self.human: int | None = None
        self.t_press: float | None = None

    def see_hand(self, landmarks: Sequence[Point], t: float) -> int | None:
        """A hand pose at time t: the human's press, the first time a landmark is in a box."""
        if self.human is None:
            pressed = self.layout.pressed(landmarks)
            if pressed is not None:
                self.human, self.t_press = pressed, t
        return self.human

    def observe(self, z_hat: np.ndarray, center: Point | None, t: float) -> None:
        """ẑ_h of the pose at time t; it counts toward the outcome until the human's press."""
        if self.t_press is None or t <= self.t_press:
            self.tracker.add(z_hat, center)

    def verdict(
        self, end: TrialEnd | None, robot: int | None, clicks: int | None
    ) -> OptionsJudgement:
        """The finished trial's judgement (`end`: how the protocol ended it)."""
        human = self.human if end is None else (self.human if end.human_pressed else None)
        t = self.tracker
        same = human is not None and robot is not None and human == robot
        outcome: Outcome | None = None
        if human is not None and robot is not None:
            outcome = ("C" if same else "D") if self.by_agreement else classify(t.switches, same)
        score = score_trial(same, clicks, t.violations, self.target_clicks)
        return OptionsJudgement(human, robot, outcome, t.switches, t.violations, score.total)
