"""Trial outcome from the human's observed path: switches, C/CH/D/DH, rule violations (SPEC §6).

Feed the ẑ_h samples (and hand centres) from "go" to the human's press, in order:

- *switches*: changes of ẑ_h's leading option (with two options, of its sign), debounced like
  Algorithm 2 — by the same debounce (`services.model.debounce`) and the same
  `DebounceParams`. The first sample with a leading option sets the initial direction (not a
  switch); afterwards a new leader counts only after C_max consecutive samples of it, and a run
  interrupted by the current leader starts over. A sample within the switch dead band (the hand
  has not moved yet, or stood still) carries no option: it neither counts toward a run nor
  breaks one.
- *outcome*: C (0 switches, same buzzer as the robot), D (0, different), CH (≥ 1, same),
  DH (≥ 1, different). A human who never pressed (timeout, `human=None`) is "different".
- *violations* (paper Remark 3): a switch is a violation when it is not the first switch of the
  trial, or when it began at or after the sample where the hand centre first crossed the commit
  line. Each offending switch is one violation, even if it breaks both rules; `extra_switches`
  and `late_switches` keep the two rules apart for analysis. A switch's onset is the first
  sample of the run that confirmed it: the moment the hand turned, not the moment the debounce
  caught up. The crossing latches: once past the line, the hand stays "crossed" for the trial.

The counting (`SwitchCounter`) is written once for any number of options; what differs is how a
ẑ_h sample names its leading option. `OptionsOutcomeTracker` is the general form (ẑ_h a
vector; no option while its half-lead over the runner-up is within the dead band,
`human_lead`); `OutcomeTracker` is its two-option kernel, the paper's (ẑ_h a number; no side
while |ẑ_h| is within the dead band), with the paper's full `TrialOutcome`. With ẑ_h = (x, −x)
the half-lead is |x| exactly, so the two count the same switches and violations
(tests/unit/test_outcome.py, hypothesis). `judge_trial` scores either.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Generic, Literal, TypeAlias, TypeVar

import numpy as np

from services.model.debounce import DebounceParams, LeaderDebouncer, option_sign, sign_option
from services.model.dynamics import leading_option
from services.model.geometry import Colour, CommitLine, Point
from services.model.scoring import score_trial

Outcome: TypeAlias = Literal["C", "CH", "D", "DH"]
OUTCOMES: tuple[Outcome, ...] = ("C", "CH", "D", "DH")


Box = TypeVar("Box")  # what a press names: a colour on the paper's table, an index over N
Z = TypeVar("Z")  # one ẑ_h sample: a number with two options, a vector over N


def classify(switches: int, human: Box | None, robot: Box) -> Outcome:
    """C / CH / D / DH from the number of switches and the two presses (colours or indices)."""
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


class SwitchCounter(ABC, Generic[Z]):
    """Switches and violations of one trial, any number of options: `add` each sample."""

    def __init__(
        self,
        debounce: DebounceParams | None = None,
        commit_line: CommitLine | None = None,
        dead_band: float = 0.0,
    ) -> None:
        """Debounce like Algorithm 2 (`debounce.c_max`); test crossings against `commit_line`.

        A sample within `dead_band` carries no option (`ObserverParams.switch_dead_band`).
        """
        self.debounce = debounce if debounce is not None else DebounceParams()
        self.commit_line = commit_line if commit_line is not None else CommitLine()
        if not (math.isfinite(dead_band) and dead_band >= 0):
            raise ValueError(f"dead_band must be finite and >= 0, got {dead_band!r}")
        self.dead_band = dead_band
        self.reset()

    @abstractmethod
    def _lead(self, z_hat: Z) -> int | None:
        """The option a sample leads with past the dead band (None: none); raises if not finite."""

    def reset(self) -> None:
        """Start a new trial."""
        self._leader = LeaderDebouncer(self.debounce.c_max)
        self._switch_indices: list[int] = []
        self._crossed_at: int | None = None

    @property
    def first(self) -> int | None:
        """The first option ẑ_h led with (None if it never led)."""
        return self._leader.first

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
        return self._leader.samples

    def add(self, z_hat: Z, center: Point | None) -> None:
        """One observation: ẑ_h and the hand centre (None when no hand was detected)."""
        lead = self._lead(z_hat)
        i = self._leader.samples
        if self._crossed_at is None and center is not None and self.commit_line.crossed(center):
            self._crossed_at = i
        if self._leader.feed_leader(lead):
            self._switch_indices.append(self._leader.onset)

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


class OutcomeTracker(SwitchCounter[float]):
    """The paper's outcome of one trial (the two-option kernel): `add` each ẑ_h, then `result`."""

    @property
    def sign(self) -> int:
        """The current debounced sign of ẑ_h (0 before the first non-zero sample)."""
        return option_sign(self._leader.leader)

    def _lead(self, z_hat: float) -> int | None:
        if not math.isfinite(z_hat):
            raise ValueError(f"z_hat must be finite, got {z_hat!r}")
        return sign_option(z_hat) if abs(z_hat) > self.dead_band else None

    def result(self, human: Colour | None, robot: Colour) -> TrialOutcome:
        """The outcome so far, given what the human (None: never pressed) and robot pressed."""
        late = self._late()
        violations = self.violations
        switches = len(self._switch_indices)
        return TrialOutcome(
            outcome=classify(switches, human, robot),
            switches=switches,
            violations=violations,
            first_sign=option_sign(self._leader.first),
            crossed_at_index=self._crossed_at,
            switch_indices=tuple(self._switch_indices),
            extra_switches=max(0, switches - 1),
            late_switches=sum(late),
            human=human,
            robot=robot,
            samples=self._leader.samples,
        )


def human_lead(z_hat: np.ndarray, dead_band: float) -> int | None:
    """ẑ_h's leading option, None when its half-lead over the runner-up is within the band.

    With two options and ẑ_h = (x, −x) the half-lead is |x|: the paper's band on |ẑ_h|.
    """
    top_two = np.sort(np.asarray(z_hat, dtype=float))[-2:]
    if 0.5 * float(top_two[1] - top_two[0]) <= dead_band:
        return None
    return leading_option(z_hat)


class OptionsOutcomeTracker(SwitchCounter[np.ndarray]):
    """Switches and violations of one trial over N options (the general form), ẑ_h vectors."""

    def _lead(self, z_hat: np.ndarray) -> int | None:
        if not np.all(np.isfinite(z_hat)):
            raise ValueError(f"z_hat must be finite, got {z_hat!r}")
        return human_lead(z_hat, self.dead_band)


@dataclass(frozen=True, slots=True)
class TrialJudgement(Generic[Box]):
    """What is stored and published for a finished trial (presses as colours or indices)."""

    human: Box | None  # None: the human never pressed (timeout)
    robot: Box | None  # None: the robot did not press
    outcome: Outcome | None  # None unless both pressed
    switches: int
    violations: int
    score: int


def judge_trial(
    tracker: SwitchCounter[Z],
    human: Box | None,
    robot: Box | None,
    clicks: int | None,
    target_clicks: int,
    by_agreement: bool = False,
) -> TrialJudgement[Box]:
    """Outcome and score of a finished trial (SPEC §6), as the conductor and offline loop store it.

    A trial the robot did not press has no outcome and scores as a different buzzer; one the
    human did not press has no outcome class either. Both keep the human's switch count and
    violations (SPEC §6: counted and stored for every trial), and the violations cost points.
    `by_agreement` labels by the buzzers alone (C same, D different), as SPEC §6 labels control
    trials by default; the switches and violations are counted and scored all the same.
    """
    same = human is not None and robot is not None and human == robot
    outcome: Outcome | None = None
    if human is not None and robot is not None:
        by_switches = classify(tracker.switches, human, robot)
        outcome = ("C" if same else "D") if by_agreement else by_switches
    score = score_trial(same, clicks, tracker.violations, target_clicks)
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
