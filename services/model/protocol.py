"""The trial protocol: the 8-trial schedule and the timeline of one trial (paper Sec 3.2, SPEC §6).

Each trial: gaze set (after the attention gesture in trial 4) → countdown "1, 2, 3, go" → both
move → the human presses (or timeout) → the robot presses → outcome and score recorded.
Times are seconds (float) from any monotonic origin, always passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, TypeAlias

from services.model.gaze import (
    GAZE_LEVEL_NAMES,
    AttentionGestureParams,
    GazeCommand,
    attention_gesture,
)
from services.model.geometry import Colour

Mode: TypeAlias = Literal["dissensus", "consensus"]


@dataclass(frozen=True, slots=True)
class TrialSpec:
    """What one trial does."""

    index: int  # 1-based trial number within a session
    mode: Mode  # "dissensus": b_r ≡ 0, controller off; "consensus": bias controller toward option
    option: Colour | None  # the convergence option O (consensus only; None in dissensus)
    gaze_level: str  # name of the gaze level (services.model.gaze.GAZE_LEVEL_NAMES)
    yaw: float  # gaze yaw (rad), > 0 toward red
    pitch: float  # gaze pitch (rad)
    attention_gesture: bool = False  # run the attention gesture before setting the gaze

    def __post_init__(self) -> None:
        if isinstance(self.index, bool) or not isinstance(self.index, int) or self.index < 1:
            raise ValueError(f"TrialSpec.index must be an integer >= 1, got {self.index!r}")
        if self.mode not in ("dissensus", "consensus"):
            raise ValueError(
                f"TrialSpec.mode must be 'dissensus' or 'consensus', got {self.mode!r}"
            )
        if self.mode == "consensus" and self.option not in ("red", "blue"):
            raise ValueError(f"trial {self.index}: consensus mode needs option 'red' or 'blue'")
        if self.mode == "dissensus" and self.option is not None:
            raise ValueError(f"trial {self.index}: dissensus mode has no option, got {self.option}")
        if self.gaze_level not in GAZE_LEVEL_NAMES:
            raise ValueError(
                f"trial {self.index}: unknown gaze level {self.gaze_level!r}; "
                f"expected one of {GAZE_LEVEL_NAMES}"
            )
        if not (math.isfinite(self.yaw) and math.isfinite(self.pitch)):
            raise ValueError(f"trial {self.index}: gaze yaw/pitch must be finite")

    @property
    def gaze(self) -> GazeCommand:
        """The gaze held from before the countdown to the end of the trial."""
        return GazeCommand(self.yaw, self.pitch)


def default_schedule() -> tuple[TrialSpec, ...]:
    """The paper's 8 trials (SPEC §5/§6): 1–3 dissensus with neutral gaze, 4–8 consensus."""
    neutral = [TrialSpec(i, "dissensus", None, "neutral", 0.0, 0.0) for i in (1, 2, 3)]
    return (
        *neutral,
        TrialSpec(4, "consensus", "blue", "minimal", -0.47, 0.31, attention_gesture=True),
        TrialSpec(5, "consensus", "red", "low", 0.53, -0.53),
        TrialSpec(6, "consensus", "red", "moderate", 0.62, -0.62),
        TrialSpec(7, "consensus", "blue", "significant", -0.72, 0.72),
        TrialSpec(8, "consensus", "red", "extreme", 1.09, -0.94),
    )


@dataclass(frozen=True, slots=True)
class ProtocolParams:
    """Session protocol settings (SPEC §6 defaults)."""

    # Words spoken by the speaker, the last one being the start signal.
    countdown: tuple[str, ...] = ("1", "2", "3", "go")
    # Time between consecutive countdown words (s); > 0.
    countdown_interval_s: float = 0.75
    # Trial end after "go" when the human has not pressed (s); > 0. The robot then presses.
    trial_timeout_s: float = 10.0
    # Pause between setting the gaze and the first countdown word (s); ≥ 0. Lets the eyes settle
    # and the participant see them before the countdown.
    gaze_lead_s: float = 1.0
    # Consecutive same-sign ẑ_h samples confirming a switch of the human's path (as Algorithm 2).
    switch_c_max: int = 4
    # Counter clicks the participant must make for the counter point.
    target_clicks: int = 10
    # The trials of a session, in order (indices 1..n).
    trials: tuple[TrialSpec, ...] = field(default_factory=default_schedule)
    # The attention gesture run before a trial that asks for it.
    gesture: AttentionGestureParams = field(default_factory=AttentionGestureParams)

    def __post_init__(self) -> None:
        if not self.countdown or not all(isinstance(w, str) and w for w in self.countdown):
            raise ValueError("ProtocolParams.countdown needs at least one non-empty word")
        for name in ("countdown_interval_s", "trial_timeout_s"):
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"ProtocolParams.{name} must be finite and > 0, got {value}")
        if not math.isfinite(self.gaze_lead_s) or self.gaze_lead_s < 0:
            raise ValueError(f"ProtocolParams.gaze_lead_s must be >= 0, got {self.gaze_lead_s}")
        for name in ("switch_c_max", "target_clicks"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"ProtocolParams.{name} must be an integer >= 1, got {value!r}")
        if not self.trials:
            raise ValueError("ProtocolParams.trials must hold at least one trial")
        indices = [t.index for t in self.trials]
        if indices != list(range(1, len(indices) + 1)):
            raise ValueError(f"ProtocolParams.trials must be numbered 1..n in order, got {indices}")


@dataclass(frozen=True, slots=True)
class TrialTimeline:
    """When each scripted event of one trial happens (s, absolute)."""

    gaze: tuple[tuple[float, GazeCommand], ...]  # gaze commands (gesture first, if any)
    countdown: tuple[tuple[float, str], ...]  # (time, word); the last word is "go"
    go_t: float  # the start signal: both agents may move
    timeout_t: float  # the robot presses the nearest buzzer if the human has not pressed

    @property
    def gaze_set_t(self) -> float:
        """Time the trial's own gaze is commanded (after any gesture)."""
        return self.gaze[-1][0]


def trial_timeline(spec: TrialSpec, start_t: float, params: ProtocolParams) -> TrialTimeline:
    """The schedule of one trial starting at `start_t` (s).

    The gaze (or the attention gesture ending in it) starts at `start_t`; the countdown's first
    word follows `gaze_lead_s` after the gaze is set, then one word per `countdown_interval_s`.
    """
    if not math.isfinite(start_t):
        raise ValueError(f"start_t must be finite, got {start_t!r}")
    if spec.attention_gesture:
        gaze = tuple(attention_gesture(start_t, spec.gaze, params.gesture))
    else:
        gaze = ((start_t, spec.gaze),)
    first_word = gaze[-1][0] + params.gaze_lead_s
    words = tuple(
        (first_word + i * params.countdown_interval_s, w) for i, w in enumerate(params.countdown)
    )
    go_t = words[-1][0]
    return TrialTimeline(gaze, words, go_t, go_t + params.trial_timeout_s)
