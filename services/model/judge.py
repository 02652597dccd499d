"""The conductor's judge of a trial: from "go" to the verdict that is stored and published.

One pure reactor for every runner of the protocol — the conductor on the fabric, the offline
closed loop — so the rules of a trial's outcome live in one place, for any number of options:

- `TrialJudge(cfg, layout, mode)` at "go": the outcome tracker with the session's debounce,
  the layout's commit line and the switch dead band, and the labelling rule of the trial's mode
  (SPEC §6: control trials by agreement alone, unless `control_labels = "switches"`).
- `see_hand(landmarks, t)`: the first pose with a landmark inside a box is the human's press
  (its time is kept: ẑ_h counts up to it).
- `observe(z_hat, center, t)`: a ẑ_h sample of a pose at time t; counted until the press.
- `verdict(end, robot, clicks)`: the human's press as the protocol counts it (a press after the
  timeout is not the person's), the outcome class and the score (SPEC §6, `judge_trial`).
- `void()`: the verdict of a trial stored interrupted — never classified, never scored.

The judge (`Judge`) is written once; what differs by N is the tracker of its ẑ_h samples.
`OptionsTrialJudge` is the general form (boxes by index, ẑ_h a vector,
`OptionsOutcomeTracker`); `TrialJudge` is its two-option kernel, the paper's (red and blue, ẑ_h
a number, `OutcomeTracker`). On the paper's table they give the same verdict
(tests/unit/test_judge_trial.py, hypothesis).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Generic, TypeVar

import numpy as np

from services.model.geometry import Colour, OptionsLayout, Point, TableLayout
from services.model.outcome import (
    OptionsOutcomeTracker,
    OutcomeTracker,
    SwitchCounter,
    TrialJudgement,
    judge_trial,
)
from services.model.params import NodConfig
from services.model.protocol import Mode, TrialEnd

Layout = TypeVar("Layout", TableLayout, OptionsLayout)
Box = TypeVar("Box")
Z = TypeVar("Z")


class Judge(ABC, Generic[Layout, Box, Z]):
    """Judges one trial from its "go", for any number of boxes."""

    def __init__(self, cfg: NodConfig, layout: Layout, mode: Mode = "consensus") -> None:
        """A judge for a `mode` trial on `layout` (the geometry in use at its "go").

        A control (dissensus) trial is labelled by agreement alone unless the protocol says
        `control_labels = "switches"` (SPEC §6).
        """
        self.layout: Layout = layout
        self.by_agreement = mode == "dissensus" and cfg.protocol.control_labels == "agreement"
        self.debounce = cfg.debounce
        self.target_clicks = cfg.protocol.target_clicks
        self.tracker: SwitchCounter[Z] = self._tracker(cfg)
        self.human: Box | None = None
        self.t_press: float | None = None  # the time of the human's press (the runner's clock)

    @abstractmethod
    def _tracker(self, cfg: NodConfig) -> SwitchCounter[Z]:
        """The trial's switch counter: the session's debounce and dead band, the commit line."""

    @abstractmethod
    def _pressed(self, landmarks: Sequence[Point]) -> Box | None:
        """The box holding any of the landmarks on `self.layout`, or None."""

    def see_hand(self, landmarks: Sequence[Point], t: float) -> Box | None:
        """A hand pose at time t: the human's press, the first time a landmark is in a box."""
        if self.human is None:
            pressed = self._pressed(landmarks)
            if pressed is not None:
                self.human, self.t_press = pressed, t
        return self.human

    def observe(self, z_hat: Z, center: Point | None, t: float) -> None:
        """ẑ_h of the pose at time t; it counts toward the outcome until the human's press."""
        if self.t_press is None or t <= self.t_press:
            self.tracker.add(z_hat, center)

    def verdict(
        self, end: TrialEnd | None, robot: Box | None, clicks: int | None
    ) -> TrialJudgement[Box]:
        """The finished trial's judgement (`end`: how the protocol ended it).

        The human's press counts only if the protocol ended the trial on it
        (`TrialEnd.counted_press`: a press seen after the timeout is not the person's choice).
        """
        human = self.human if end is None or end.human_pressed else None
        return judge_trial(
            self.tracker, human, robot, clicks, self.target_clicks, self.by_agreement
        )

    @staticmethod
    def void() -> TrialJudgement[Box]:
        """The judgement of a trial stored interrupted: no presses, no outcome, no points.

        Its attempts were broken before a verdict, so nothing of them is the person's choice.
        """
        return TrialJudgement(human=None, robot=None, outcome=None, switches=0, violations=0,
                              score=0)


class TrialJudge(Judge[TableLayout, Colour, float]):
    """The paper's judge (the two-option kernel): red and blue, ẑ_h a number."""

    def _tracker(self, cfg: NodConfig) -> OutcomeTracker:
        dead_band = cfg.decision.observer.switch_dead_band
        return OutcomeTracker(cfg.debounce, self.layout.commit, dead_band)

    def _pressed(self, landmarks: Sequence[Point]) -> Colour | None:
        return self.layout.pressed(landmarks)


class OptionsTrialJudge(Judge[OptionsLayout, int, np.ndarray]):
    """The judge over N boxes (the general form): option indices, ẑ_h a vector."""

    def _tracker(self, cfg: NodConfig) -> OptionsOutcomeTracker:
        dead_band = cfg.decision.observer.switch_dead_band
        return OptionsOutcomeTracker(cfg.debounce, self.layout.commit, dead_band)

    def _pressed(self, landmarks: Sequence[Point]) -> int | None:
        return self.layout.pressed(landmarks)
