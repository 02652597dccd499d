"""The conductor's judge of a trial: from "go" to the verdict that is stored and published.

One pure reactor for every runner of the protocol — the conductor on the fabric, the offline
closed loop — so the rules of a trial's outcome live in one place:

- `TrialJudge(cfg, layout, mode)` at "go": the outcome tracker with the session's debounce,
  commit line and switch dead band, and the labelling rule of the trial's mode (SPEC §6: control
  trials by agreement alone, unless `control_labels = "switches"`).
- `see_hand(landmarks, t)`: the first pose with a landmark inside a buzzer box is the human's
  press (its time is kept: ẑ_h counts up to it).
- `observe(z_hat, center, t)`: a ẑ_h sample of a pose at time t; counted until the press.
- `verdict(end, robot, clicks)`: the human's press as the protocol counts it (a press after the
  timeout is not the person's), the outcome class and the score (SPEC §6, `judge_trial`).
- `void()`: the verdict of a trial stored interrupted — never classified, never scored.
"""

from __future__ import annotations

from collections.abc import Sequence

from services.model.geometry import Colour, Point, TableLayout
from services.model.outcome import OutcomeTracker, TrialJudgement, judge_trial
from services.model.params import NodConfig
from services.model.protocol import Mode, TrialEnd


class TrialJudge:
    """Judges one trial from its "go"."""

    def __init__(self, cfg: NodConfig, layout: TableLayout, mode: Mode = "consensus") -> None:
        """A judge for a `mode` trial on `layout` (the geometry in use at its "go").

        A control (dissensus) trial is labelled by agreement alone unless the protocol says
        `control_labels = "switches"` (SPEC §6).
        """
        self.layout = layout
        self.by_agreement = mode == "dissensus" and cfg.protocol.control_labels == "agreement"
        self.debounce = cfg.debounce
        self.target_clicks = cfg.protocol.target_clicks
        self.tracker = OutcomeTracker(
            cfg.debounce, layout.commit, cfg.decision.observer.switch_dead_band
        )
        self.human: Colour | None = None
        self.t_press: float | None = None  # the time of the human's press (the runner's clock)

    def see_hand(self, landmarks: Sequence[Point], t: float) -> Colour | None:
        """A hand pose at time t: the human's press, the first time a landmark is in a box."""
        if self.human is None:
            pressed = self.layout.pressed(landmarks)
            if pressed is not None:
                self.human, self.t_press = pressed, t
        return self.human

    def observe(self, z_hat: float, center: Point | None, t: float) -> None:
        """ẑ_h of the pose at time t; it counts toward the outcome until the human's press."""
        if self.t_press is None or t <= self.t_press:
            self.tracker.add(z_hat, center)

    def verdict(
        self, end: TrialEnd | None, robot: Colour | None, clicks: int | None
    ) -> TrialJudgement:
        """The finished trial's judgement (`end`: how the protocol ended it)."""
        human = self.human if end is None else end.counted_press(self.human)
        return judge_trial(
            self.tracker, human, robot, clicks, self.target_clicks, self.by_agreement
        )

    @staticmethod
    def void() -> TrialJudgement:
        """The judgement of a trial stored interrupted: no presses, no outcome, no points.

        Its attempts were broken before a verdict, so nothing of them is the person's choice.
        """
        return TrialJudgement(human=None, robot=None, outcome=None, switches=0, violations=0,
                              score=0)
