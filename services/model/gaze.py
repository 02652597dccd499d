"""Gaze levels, the gaze toward an option of N ≥ 2, and the attention gesture (paper Sec 5).

Angles are in radians: yaw ψ positive looks toward +x (the paper's red side), pitch φ as printed
in the paper. Both eyes move in unison, so one `GazeCommand` drives all four servos (see
`servos.py`). Time is in seconds (float) and always passed in.

The gaze toward option j over a table of N boxes (docs/multi-option.md, decision 12):

- **two boxes, one on each side of the eyes (the paper's table):** the printed row of the
  paper's gaze table, toward the box's side (`GazeLevel.toward`: red on +x, blue mirrored). This
  is the module's two-option kernel, chosen inside `gaze_toward` and `read_gaze`;
- **any N (the general form, `geometric_gaze`):** the eyes sit at `EYES`, midway on the robot's
  side of the table, `EYES_HEIGHT` above it; neutral looks at the participant's resting hand
  `PARTICIPANT`; a level looks from there toward the box by the share |yaw_level| / |yaw_extreme|
  of the way ("extreme" at the box itself). Yaw is the bearing of that point from the eyes;
  pitch how much lower than the hand the eyes look, negative looking down (the middle box of
  three is told from the neutral gaze by its pitch alone). A row of three puts a box straight
  ahead, where a yaw-only cue would be the neutral gaze, so N ≥ 3 needs it.

A person reads a gaze as (option, strength): the box it points toward and the level's |yaw| in
the paper's table, so a level pulls as hard for any N (`Participant.go`: gaze_gain · |yaw| ·
trust). The two forms give different angles at N = 2 (the geometric ones are smaller: minimal
±0.22 rad against the printed 0.47), but the same cue: the same option and strength (1e-12),
and the same side (tests/unit/test_gaze.py checks it at N = 2 on random tables).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, TypeAlias

from services.model.geometry import Colour, OptionsLayout, Point

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


EYES: Point = (0.5, 0.0)  # above the arm's home (0.5, 0.08), on the table's far edge
EYES_HEIGHT = 0.25  # normalised table units above the table
PARTICIPANT: Point = (0.5, 0.85)  # the resting hand (ParticipantParams.start): neutral gaze
_EXTREME = abs(GAZE_LEVELS["extreme"].yaw)
_NO_CUE = 1e-9  # |yaw| (rad) at or below which the paper's person reads no cue


def cue_strength(level: str) -> float:
    """A level's strength: its |yaw| in the paper's table (0 for neutral, 1.09 for extreme)."""
    return abs(gaze_level(level).yaw)


def _paper_sides(layout: OptionsLayout) -> tuple[int, int] | None:
    """(the +x box, the other) on the paper's table: two boxes, one each side of the eyes."""
    if layout.n_options != 2:
        return None
    x0, x1 = (box.center[0] for box in layout.boxes)
    if x0 > EYES[0] > x1:
        return 0, 1
    if x1 > EYES[0] > x0:
        return 1, 0
    return None


def _depression(p: Point) -> float:
    """The angle below the horizontal at which the eyes see a point of the table."""
    return math.atan2(EYES_HEIGHT, math.dist(EYES, p))


def look_at(p: Point) -> GazeCommand:
    """The gaze that looks at table point p."""
    yaw = math.atan2(p[0] - EYES[0], p[1] - EYES[1])
    return GazeCommand(yaw, _depression(PARTICIPANT) - _depression(p))


def gaze_point(layout: OptionsLayout, option: int | None, level: str) -> Point:
    """Where a level's geometric gaze toward `option` looks (None or "neutral": the hand)."""
    share = cue_strength(level) / _EXTREME
    if option is None or share == 0.0:
        return PARTICIPANT
    cx, cy = layout.boxes[option].center
    px, py = PARTICIPANT
    return (px + share * (cx - px), py + share * (cy - py))


def geometric_gaze(layout: OptionsLayout, option: int | None, level: str) -> GazeCommand:
    """The general form for any N: the eyes look at `gaze_point` (module doc)."""
    if option is None or cue_strength(level) == 0.0:
        return GazeCommand()
    return look_at(gaze_point(layout, option, level))


def gaze_toward(layout: OptionsLayout, option: int | None, level: str) -> GazeCommand:
    """The eyes' command for a level toward `option` on this table.

    On the paper's table (two boxes, one each side) the paper's printed row toward the box's
    side (the two-option kernel); otherwise `geometric_gaze`.
    """
    sides = _paper_sides(layout)
    if sides is None:
        return geometric_gaze(layout, option, level)
    if option is None:
        return GazeCommand()
    if option not in sides:
        raise IndexError(f"box {option} is not on this table of 2 boxes")
    return gaze_level(level).toward("red" if option == sides[0] else "blue")


def read_geometric_gaze(layout: OptionsLayout, gaze: GazeCommand) -> tuple[int | None, float]:
    """The general reading for any N: the box the gaze points toward from the hand.

    Strength: the level's |yaw| in the paper's table, from how far toward the box the eyes
    look. The neutral gaze, or one at or above the horizon, is no cue: (None, 0.0).
    """
    depression = _depression(PARTICIPANT) - gaze.pitch
    if depression <= 0 or (gaze.yaw == 0.0 and gaze.pitch == 0.0):
        return None, 0.0
    reach = EYES_HEIGHT / math.tan(depression)
    g = (EYES[0] + reach * math.sin(gaze.yaw), EYES[1] + reach * math.cos(gaze.yaw))
    gx, gy = g[0] - PARTICIPANT[0], g[1] - PARTICIPANT[1]
    seen = math.hypot(gx, gy)
    if seen < 1e-9:
        return None, 0.0
    best, best_cos, best_len = None, -2.0, 1.0
    for j, box in enumerate(layout.boxes):
        bx, by = box.center[0] - PARTICIPANT[0], box.center[1] - PARTICIPANT[1]
        length = math.hypot(bx, by)
        cos = (gx * bx + gy * by) / (seen * length)
        if cos > best_cos:
            best, best_cos, best_len = j, cos, length
    return best, min(_EXTREME, _EXTREME * seen / best_len)


def read_gaze(layout: OptionsLayout, gaze: GazeCommand) -> tuple[int | None, float]:
    """(option, strength) a person reads from a gaze on this table.

    On the paper's table the paper's person's reading (the two-option kernel): the box on the
    side of the yaw, strength |yaw|, no cue at |yaw| ≤ 1e-9 (`Participant.go`); otherwise
    `read_geometric_gaze`.
    """
    sides = _paper_sides(layout)
    if sides is None:
        return read_geometric_gaze(layout, gaze)
    if abs(gaze.yaw) <= _NO_CUE:
        return None, 0.0
    return sides[0] if gaze.yaw > 0 else sides[1], abs(gaze.yaw)


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
