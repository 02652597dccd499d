"""Gaze over N_o boxes: the eyes look at a point of the table, from the layout's geometry.

The paper's gaze table has a yaw and a pitch per level for two boxes, one on each side; a row
of three puts a box straight ahead, where a yaw-only cue would be the neutral gaze. So the
N_o-option gaze is geometric (docs/multi-option.md):

- the eyes sit at `EYES`, midway on the robot's side of the table, `EYES_HEIGHT` above it;
  neutral (yaw = pitch = 0) looks at the participant's resting hand `PARTICIPANT`;
- a level looks from there toward option j's box by the share |yaw_level| / |yaw_extreme| of
  the way: "extreme" looks at the box itself, "minimal" 43 % of the way;
- yaw = the bearing of that point from the eyes (> 0 toward +x, the side of the paper's red
  box); pitch = how much lower than the participant's hand the eyes look, negative looking
  down (the middle box of three is told from the neutral gaze by its pitch alone).

`read_gaze` inverts it: the option whose direction from the hand the gaze point lies along,
and the cue's strength as the level's |yaw|, so a simulated person feels the same pull from a
level as the two-option person does (`Participant.go`: gaze_gain · |yaw| · trust).
"""

from __future__ import annotations

import math

from services.model.gaze import GAZE_LEVELS, GazeCommand, gaze_level
from services.model.geometry import Point
from services.model.options_geometry import OptionsLayout

EYES: Point = (0.5, 0.0)  # above the arm's home (0.5, 0.08), on the table's far edge
EYES_HEIGHT = 0.25  # normalised table units above the table
PARTICIPANT: Point = (0.5, 0.85)  # the resting hand (ParticipantParams.start): neutral gaze
_EXTREME = abs(GAZE_LEVELS["extreme"].yaw)


def cue_strength(level: str) -> float:
    """A level's strength: its |yaw| in the paper's table (0 for neutral, 1.09 for extreme)."""
    return abs(gaze_level(level).yaw)


def _depression(p: Point) -> float:
    """The angle below the horizontal at which the eyes see a point of the table."""
    return math.atan2(EYES_HEIGHT, math.dist(EYES, p))


def look_at(p: Point) -> GazeCommand:
    """The gaze that looks at table point p."""
    yaw = math.atan2(p[0] - EYES[0], p[1] - EYES[1])
    return GazeCommand(yaw, _depression(PARTICIPANT) - _depression(p))


def gaze_point(layout: OptionsLayout, option: int | None, level: str) -> Point:
    """Where a level's gaze toward `option` looks (None or "neutral": at the participant)."""
    share = cue_strength(level) / _EXTREME
    if option is None or share == 0.0:
        return PARTICIPANT
    cx, cy = layout.boxes[option].center
    px, py = PARTICIPANT
    return (px + share * (cx - px), py + share * (cy - py))


def gaze_toward(layout: OptionsLayout, option: int | None, level: str) -> GazeCommand:
    """The eyes' command for a level toward `option` on this table."""
    if option is None or cue_strength(level) == 0.0:
        return GazeCommand()
    return look_at(gaze_point(layout, option, level))


def read_gaze(layout: OptionsLayout, gaze: GazeCommand) -> tuple[int | None, float]:
    """(option, strength) a person reads from a gaze: the box it points toward from the hand.

    The neutral gaze, or one at or above the horizon, is no cue: (None, 0.0).
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
