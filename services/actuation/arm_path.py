"""The arm's calibrated poses and the path between them (pure; no bus, no clock).

Five joint poses, recorded by `nod actuation calibrate`, span the path of a buzzer-pressing arm:

    press_blue            press_red
        |                     |
    above_blue --- home --- above_red          s ∈ [−1, 1] along the row, d ∈ [0, 1] down

`pose_at(s, d)` interpolates the joints linearly, so every goal lies between calibrated poses;
`locate(present)` finds the path point nearest to measured joint positions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from services.model.geometry import COLOURS, Colour, colour_sign

POSE_NAMES: tuple[str, ...] = ("home", "above_red", "press_red", "above_blue", "press_blue")
Pose = tuple[int, ...]


@dataclass(frozen=True, slots=True)
class ArmPoses:
    """Joint positions (servo steps, in `ids` order) of the five calibrated poses.

    Empty by default: an arm without recorded poses refuses to move (no guessed defaults).
    """

    home: Pose = ()  # rest, clear of both buzzers
    above_red: Pose = ()  # hovering over the red buzzer
    press_red: Pose = ()  # the red buzzer pressed down
    above_blue: Pose = ()  # hovering over the blue buzzer
    press_blue: Pose = ()  # the blue buzzer pressed down

    def __post_init__(self) -> None:
        lengths = {len(getattr(self, n)) for n in POSE_NAMES}
        if len(lengths) != 1:
            raise ValueError(f"every pose needs one position per joint; got lengths {lengths}")

    @property
    def calibrated(self) -> bool:
        """Whether the poses were recorded."""
        return len(self.home) > 0

    def above(self, colour: Colour) -> Pose:
        """The hover pose over a buzzer."""
        return self.above_red if colour == "red" else self.above_blue

    def pressed(self, colour: Colour) -> Pose:
        """The pose pressing a buzzer."""
        return self.press_red if colour == "red" else self.press_blue


def pose_distance(a: Pose, b: Pose) -> int:
    """The largest difference of one joint between two poses (servo steps, Chebyshev)."""
    return max((abs(x - y) for x, y in zip(a, b, strict=True)), default=0)


def _lerp(a: Pose, b: Pose, u: float) -> tuple[float, ...]:
    return tuple(x + (y - x) * u for x, y in zip(a, b, strict=True))


def pose_at(poses: ArmPoses, s: float, d: float) -> Pose:
    """Joint goals at path parameter s ∈ [−1, 1] and descent d ∈ [0, 1], rounded to steps."""
    colour: Colour = "red" if s >= 0 else "blue"
    row = _lerp(poses.home, poses.above(colour), abs(s))
    if d > 0:  # descent only happens at |s| = 1
        above, down = poses.above(colour), poses.pressed(colour)
        row = tuple(r + (q - a) * d for r, a, q in zip(row, above, down, strict=True))
    return tuple(round(v) for v in row)


def _project(p: Pose, a: Pose, b: Pose) -> tuple[float, float]:
    """(u ∈ [0, 1], squared distance) of the point of segment a→b nearest to p."""
    ab = [y - x for x, y in zip(a, b, strict=True)]
    norm = sum(v * v for v in ab)
    u = 0.0 if norm == 0 else sum((q - x) * v for q, x, v in zip(p, a, ab, strict=True)) / norm
    u = min(max(u, 0.0), 1.0)
    return u, sum((q - w) ** 2 for q, w in zip(p, _lerp(a, b, u), strict=True))


def locate(poses: ArmPoses, present: Pose) -> tuple[float, float]:
    """(s, d) of the path point nearest to the present joint positions (after a (re)connect)."""
    best = (math.inf, 0.0, 0.0)
    for colour in COLOURS:
        sign = colour_sign(colour)
        u, dist = _project(present, poses.home, poses.above(colour))
        best = min(best, (dist, sign * u, 0.0))
        u, dist = _project(present, poses.above(colour), poses.pressed(colour))
        best = min(best, (dist, float(sign), u))
    return best[1], best[2]
