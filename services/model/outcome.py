"""Trial outcome from the human's observed path: switches, C/CH/D/DH, rule violations (SPEC §6).

Feed the ẑ_h samples (and hand centres) from "go" to the human's press, in order:

- *switches*: sign changes of ẑ_h, debounced like Algorithm 2 — by the same `SignDebouncer`
  and the same `DebounceParams`. The first non-zero sample sets the initial direction (not a
  switch); afterwards a new sign counts only after C_max consecutive samples of it, and a run
  interrupted by the current sign starts over. A zero sample (the hand has not moved yet, or
  stood still) carries no sign: it neither counts toward a run nor breaks one.
- *outcome*: C (0 switches, same buzzer as the robot), D (0, different), CH (≥ 1, same),
  DH (≥ 1, different). A human who never pressed (timeout, `human=None`) is "different".
- *violations* (paper Remark 3): a switch is a violation when it is not the first switch of the
  trial, or when it began at or after the sample where the hand centre first crossed the commit
  line. Each offending switch is one violation, even if it breaks both rules; `extra_switches`
  and `late_switches` keep the two rules apart for analysis. A switch's onset is the first
  sample of the run that confirmed it: the moment the hand turned, not the moment the debounce
  caught up. The crossing latches: once past the line, the hand stays "crossed" for the trial.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, TypeAlias

from services.model.debounce import DebounceParams, SignDebouncer
from services.model.geometry import Colour, CommitLine, Point
from services.model.scoring import score_trial

Outcome: TypeAlias = Literal["C", "CH", "D", "DH"]
OUTCOMES: tuple[Outcome, ...] = ("C", "CH", "D", "DH")


def classify(switches: int, human: Colour | None, robot: Colour) -> Outcome:
    """C / CH / D / DH from the number of switches and the two presses."""
    if switches < 0:
        raise ValueError(f"switches must be >= 0, got {switches}")
    same = human is not None and human == robot
    if switches == 0:
        return "C" if same else "D"
    return "CH" if same else "DH"


@dataclass(frozen=True, slots=True)
class TrialOutcome:
    """Everything the outcome of one trial is made of."""

    outcome: Outcome
    switches: int  # debounced sign changes of ẑ_h
    violations: int  # offending switches (see module docstring)
    first_sign: int  # +1 red, −1 blue, 0 if ẑ_h never left zero
    crossed_at_index: int | None  # first sample past the commit line, None if never crossed
    switch_indices: tuple[int, ...]  # onset sample index of each switch
    extra_switches: int  # switches beyond the first
    late_switches: int  # switches with onset at or after the crossing
    human: Colour | None  # buzzer the human pressed, None on timeout
    robot: Colour  # buzzer the robot pressed
    samples: int  # samples fed

    @property
    def same_buzzer(self) -> bool:
        """Whether human and robot pressed the same buzzer."""
        return self.human is not None and self.human == self.robot


class OutcomeTracker:
    """Incremental outcome of one trial: `add` each sample, then `result`."""

    def __init__(
        self,
        debounce: DebounceParams | None = None,
        commit_line: CommitLine | None = None,
        dead_band: float = 0.0,
    ) -> None:
        """Debounce like Algorithm 2 (`debounce.c_max`); test crossings against `commit_line`.

        A sample with |ẑ_h| ≤ `dead_band` carries no side (`ObserverParams.switch_dead_band`).
        """
        self.debounce = debounce if debounce is not None else DebounceParams()
        self.commit_line = commit_line if commit_line is not None else CommitLine()
        if not (math.isfinite(dead_band) and dead_band >= 0):
            raise ValueError(f"dead_band must be finite and >= 0, got {dead_band!r}")
        self.dead_band = dead_band
        self.reset()

    def reset(self) -> None:
        """Start a new trial."""
        self._sign = SignDebouncer(self.debounce.c_max)
        self._switch_indices: list[int] = []
        self._crossed_at: int | None = None

    @property
    def sign(self) -> int:
        """The current debounced sign of ẑ_h (0 before the first non-zero sample)."""
        return self._sign.sign

    @property
    def switches(self) -> int:
        """Switches confirmed so far."""
        return len(self._switch_indices)

    @property
    def crossed_at_index(self) -> int | None:
        """Index of the first sample past the commit line, or None."""
        return self._crossed_at

    @property
    def samples(self) -> int:
        """Samples fed so far."""
        return self._sign.samples

    def add(self, z_hat: float, center: Point | None) -> None:
        """One observation: ẑ_h and the hand centre (None when no hand was detected)."""
        if not math.isfinite(z_hat):
            raise ValueError(f"z_hat must be finite, got {z_hat!r}")
        i = self._sign.samples
        if self._crossed_at is None and center is not None and self.commit_line.crossed(center):
            self._crossed_at = i
        if self._sign.feed(z_hat if abs(z_hat) > self.dead_band else 0.0):
            self._switch_indices.append(self._sign.onset)

    def _late(self) -> list[bool]:
        """Per confirmed switch: whether it began after the hand crossed the commit line."""
        return [
            self._crossed_at is not None and onset >= self._crossed_at
            for onset in self._switch_indices
        ]

    @property
    def violations(self) -> int:
        """Rule violations so far: every switch after the first, and every late one (SPEC §6)."""
        return sum(1 for k, is_late in enumerate(self._late()) if k >= 1 or is_late)

    def result(self, human: Colour | None, robot: Colour) -> TrialOutcome:
        """The outcome so far, given what the human (None: never pressed) and robot pressed."""
        late = self._late()
        violations = self.violations
        switches = len(self._switch_indices)
        return TrialOutcome(
            outcome=classify(switches, human, robot),
            switches=switches,
            violations=violations,
            first_sign=self._sign.first_sign,
            crossed_at_index=self._crossed_at,
            switch_indices=tuple(self._switch_indices),
            extra_switches=max(0, switches - 1),
            late_switches=sum(late),
            human=human,
            robot=robot,
            samples=self._sign.samples,
        )


@dataclass(frozen=True, slots=True)
class TrialJudgement:
    """What is stored and published for a finished trial."""

    human: Colour | None  # None: the human never pressed (timeout)
    robot: Colour | None  # None: the robot did not press
    outcome: Outcome | None  # None unless both pressed
    switches: int
    violations: int
    score: int


def judge_trial(
    tracker: OutcomeTracker,
    human: Colour | None,
    robot: Colour | None,
    clicks: int | None,
    target_clicks: int,
    by_agreement: bool = False,
) -> TrialJudgement:
    """Outcome and score of a finished trial (SPEC §6), as the conductor and offline loop store it.

    A trial the robot did not press has no outcome and scores as a different buzzer; one the
    human did not press has no outcome class either. Both keep the human's switch count and
    violations (SPEC §6: counted and stored for every trial), and the violations cost points.
    `by_agreement` labels by the buzzers alone (C same, D different), as SPEC §6 labels control
    trials by default; the switches and violations are counted and scored all the same.
    """
    result = tracker.result(human, robot) if robot is not None else None
    outcome = result.outcome if (result is not None and human is not None) else None
    if outcome is not None and result is not None and by_agreement:
        outcome = "C" if result.same_buzzer else "D"
    score = score_trial(
        result is not None and result.same_buzzer, clicks, tracker.violations, target_clicks
    )
    return TrialJudgement(
        human=human,
        robot=robot,
        outcome=outcome,
        switches=tracker.switches,
        violations=tracker.violations,
        score=score.total,
    )


def count_switches(z_hats: Sequence[float], debounce: DebounceParams | None = None) -> int:
    """Debounced sign changes of a ẑ_h sequence."""
    tracker = OutcomeTracker(debounce)
    for z in z_hats:
        tracker.add(z, None)
    return tracker.switches


def trial_outcome(
    z_hats: Sequence[float],
    centers: Sequence[Point | None],
    human: Colour | None,
    robot: Colour,
    debounce: DebounceParams | None = None,
    commit_line: CommitLine | None = None,
) -> TrialOutcome:
    """The outcome of a whole recorded trial (samples from "go" to the human's press)."""
    if len(z_hats) != len(centers):
        raise ValueError(f"got {len(z_hats)} ẑ_h samples but {len(centers)} hand centres")
    tracker = OutcomeTracker(debounce, commit_line)
    for z, c in zip(z_hats, centers, strict=True):
        tracker.add(z, c)
    return tracker.result(human, robot)
