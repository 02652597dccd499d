"""Gaze levels and the attention gesture of the robotic eyes (paper Sec 5, SPEC §5).

Angles are in radians: yaw ψ positive looks toward red, pitch φ as printed in the paper. Both
eyes move in unison, so one `GazeCommand` drives all four servos (see `servos.py`). Time is in
seconds (float) and always passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, TypeAlias

from services.model.geometry import Colour

GazeLevelName: TypeAlias = Literal[
    "neutral", "minimal", "low", "moderate", "significant", "extreme"
]
GAZE_LEVEL_NAMES: tuple[GazeLevelName, ...] = (
    "neutral",
    "minimal",
    "low",
    "moderate",
    "significant",
    "extreme",
)


@dataclass(frozen=True, slots=True)
class GazeCommand:
    """Where both eyes look: yaw and pitch (rad) from the neutral centre."""

    yaw: float = 0.0  # rad; > 0 toward red
    pitch: float = 0.0  # rad; sign as in the paper's table

    def __post_init__(self) -> None:
        if not (math.isfinite(self.yaw) and math.isfinite(self.pitch)):
            raise ValueError(f"gaze angles must be finite, got yaw={self.yaw}, pitch={self.pitch}")


@dataclass(frozen=True, slots=True)
class GazeLevel:
    """One row of the paper's gaze table.

    A named intensity, the option the paper showed it for, and the angles printed for it.
    """

    name: GazeLevelName
    option: Colour | None  # option the paper used this level for (None: neutral)
    yaw: float  # rad, as printed
    pitch: float  # rad, as printed

    def toward(self, option: Colour | None) -> GazeCommand:
        """Return the gaze of this level toward an option.

        The printed row is returned for its own option. For the other option both angles are
        mirrored: in every printed row pitch has the opposite sign of yaw, and mirroring both
        keeps that pattern. The neutral level ignores the option.
        """
        if self.option is None or option is None or option == self.option:
            return GazeCommand(self.yaw, self.pitch)
        return GazeCommand(-self.yaw, -self.pitch)


# Paper Sec 5 / SPEC §5, trials 1–3 and 4–8 in order.
GAZE_LEVELS: dict[GazeLevelName, GazeLevel] = {
    "neutral": GazeLevel("neutral", None, 0.0, 0.0),
    "minimal": GazeLevel("minimal", "blue", -0.47, 0.31),
    "low": GazeLevel("low", "red", 0.53, -0.53),
    "moderate": GazeLevel("moderate", "red", 0.62, -0.62),
    "significant": GazeLevel("significant", "blue", -0.72, 0.72),
    "extreme": GazeLevel("extreme", "red", 1.09, -0.94),
}


def gaze_level(name: str) -> GazeLevel:
    """Look a level up by name, with an error listing the valid names."""
    try:
        return GAZE_LEVELS[name]  # type: ignore[index]
    except KeyError:
        raise ValueError(
            f"unknown gaze level {name!r}; expected one of {GAZE_LEVEL_NAMES}"
        ) from None


MAX_GESTURE_STEP_S = 10.0  # one pose of the attention gesture (the paper's is under a second)
MAX_FLICKS = 20


@dataclass(frozen=True, slots=True)
class AttentionGestureParams:
    """The attention-grabbing move before trial 4: eyes near their limit toward red, then settle."""

    # Yaw of the "limit" pose (rad), toward red. 1.4 rad ≈ 80°: near the ±90° servo travel but
    # short of the mechanical stop, so the servos do not stall against it.
    limit_yaw: float = 1.4
    # Pitch of the limit pose (rad).
    limit_pitch: float = 0.0
    # Time at the limit pose before settling (s); > 0.
    hold_s: float = 0.6
    # Extra flicks between the limit and neutral before the final hold; ≥ 0. Each is one
    # `flick_s` at the limit and one at neutral. The paper describes a single excursion (0).
    flicks: int = 0
    # Duration of each half-flick (s); > 0.
    flick_s: float = 0.25

    def __post_init__(self) -> None:
        for name in ("limit_yaw", "limit_pitch", "hold_s", "flick_s"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"AttentionGestureParams.{name} must be finite")
        # The poses travel as gaze messages, whose angles are in [-pi, pi] (beyond, the eyes
        # refuse them); the times and the flicks are bounded so that a typo cannot stretch one
        # gesture over minutes or build a billion poses (`attention_gesture` lists each one).
        if not 0 < self.limit_yaw <= math.pi:
            raise ValueError(
                f"AttentionGestureParams.limit_yaw must be in (0, pi] (toward red), got "
                f"{self.limit_yaw!r}"
            )
        if not abs(self.limit_pitch) <= math.pi:
            raise ValueError(
                f"AttentionGestureParams.limit_pitch must be in [-pi, pi], got {self.limit_pitch!r}"
            )
        for name in ("hold_s", "flick_s"):
            if not 0 < getattr(self, name) <= MAX_GESTURE_STEP_S:
                raise ValueError(
                    f"AttentionGestureParams.{name} must be in (0, {MAX_GESTURE_STEP_S:g}] s, "
                    f"got {getattr(self, name)!r}"
                )
        flicks = self.flicks
        if isinstance(flicks, bool) or not isinstance(flicks, int) or not 0 <= flicks <= MAX_FLICKS:
            raise ValueError(
                f"AttentionGestureParams.flicks must be an integer in [0, {MAX_FLICKS}], got "
                f"{flicks!r}"
            )

    @property
    def duration_s(self) -> float:
        """Time from the gesture's start to the settle command (s)."""
        return 2 * self.flicks * self.flick_s + self.hold_s


def attention_gesture(
    start_t: float = 0.0,
    settle: GazeCommand | None = None,
    params: AttentionGestureParams | None = None,
) -> list[tuple[float, GazeCommand]]:
    """The gesture as (time, command) pairs, times absolute from `start_t` (s).

    With the default `start_t = 0` the times are offsets. The last command is `settle` (the
    trial's gaze; default: the minimal level toward blue, trial 4's), at
    `start_t + params.duration_s`; the eyes hold it to the end of the trial.
    """
    p = params if params is not None else AttentionGestureParams()
    if settle is None:
        settle = GAZE_LEVELS["minimal"].toward("blue")
    if not math.isfinite(start_t):
        raise ValueError(f"start_t must be finite, got {start_t!r}")
    limit = GazeCommand(p.limit_yaw, p.limit_pitch)
    neutral = GazeCommand()
    out: list[tuple[float, GazeCommand]] = []
    t = start_t
    for _ in range(p.flicks):
        out.append((t, limit))
        out.append((t + p.flick_s, neutral))
        t += 2 * p.flick_s
    out.append((t, limit))
    out.append((t + p.hold_s, settle))
    return out
