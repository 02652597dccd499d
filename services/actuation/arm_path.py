"""The arm's calibrated poses and the path between them (pure; no bus, no clock).

A rest pose and, for each option by name, a pose above its buzzer and one pressing it, recorded
by `nod actuation calibrate`, span the path of a buzzer-pressing arm: a star of spokes from home,
one per box, each ending in a descent. The paper's table is its two-option case:

    press_blue            press_red
        |                     |
    above_blue --- home --- above_red          u ∈ [0, 1] out along a spoke, d ∈ [0, 1] down

A place on the path is (box, u, d); `pose_on` interpolates the joints linearly, so every goal
lies between calibrated poses, and `locate_on` finds the place nearest to measured joints. The
paper's coordinate s ∈ [−1, 1] (+u toward red, −u toward blue) is kept by `pose_at` and `locate`
on top of them: one path, two ways of naming a place on it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from services.model.geometry import COLOURS

Pose = tuple[int, ...]
KINDS: tuple[str, ...] = ("above", "press")  # the two poses of a box, in the order recorded


def pose_names(names: Iterable[str]) -> tuple[str, ...]:
    """The poses of an arm over these options, in the order calibration records them."""
    return ("home", *(f"{kind}_{name}" for name in names for kind in KINDS))


POSE_NAMES: tuple[str, ...] = pose_names(COLOURS)  # the paper's five


@dataclass(frozen=True, slots=True, init=False)
class ArmPoses:
    """Joint positions (servo steps, in `ids` order): home, and above/press per option by name.

    Built as the arm file's `[poses]` table reads, `home=…, above_red=…, press_red=…`, one
    `above_<option>` and `press_<option>` for each option (the paper's positional order
    `ArmPoses(home, above_red, press_red, above_blue, press_blue)` too); the same keys read
    back as attributes (`poses.press_red`). Empty by default: an arm without recorded poses
    refuses to move (no guessed defaults).
    """

    home: Pose
    boxes: tuple[tuple[str, Pose, Pose], ...]  # (option name, above, press), as recorded

    def __init__(self, home: Pose = (), *paper: Pose, **named: Pose) -> None:
        """Poses by the file's keys; a key that names no pose, or a box half given, refused."""
        if len(paper) > len(POSE_NAMES) - 1:
            raise TypeError(f"ArmPoses takes at most {len(POSE_NAMES)} poses by position")
        for key, pose in zip(POSE_NAMES[1:], paper, strict=False):
            if key in named:
                raise TypeError(f"ArmPoses got pose {key} twice")
            named[key] = pose
        halves: dict[str, dict[str, Pose]] = {}
        for key, pose in named.items():
            kind, _, name = key.partition("_")
            if kind not in KINDS or not name:
                raise ValueError(
                    f"unknown pose {key!r}: the poses are home, above_<option>, press_<option>"
                )
            halves.setdefault(name, {})[kind] = tuple(pose)
        for name, half in halves.items():
            if len(half) != len(KINDS):
                have, lack = next(iter(half)), next(k for k in KINDS if k not in half)
                raise ValueError(f"pose {have}_{name} has no {lack}_{name}")
        boxes = tuple((name, h["above"], h["press"]) for name, h in halves.items())
        lengths = {len(home)} | {len(p) for _, above, press in boxes for p in (above, press)}
        if len(lengths) != 1:
            raise ValueError(f"every pose needs one position per joint; got lengths {lengths}")
        if lengths == {0}:
            boxes = ()  # nothing recorded: the empty file of an uncalibrated arm
        elif len(boxes) < 2:
            raise ValueError(f"the poses need two options or more, got {[b[0] for b in boxes]}")
        object.__setattr__(self, "home", tuple(home))
        object.__setattr__(self, "boxes", boxes)

    @classmethod
    def from_config_table(cls, data: Mapping[str, Any]) -> ArmPoses:
        """The `[poses]` table of an arm file (`from_mapping` reads it through this)."""
        poses: dict[str, Pose] = {}
        for key, value in data.items():
            if not isinstance(value, list | tuple) or not all(
                isinstance(v, int) and not isinstance(v, bool) for v in value
            ):
                raise ValueError(f"{key}: expected an array of integers, got {value!r}")
            poses[key] = tuple(value)
        return cls(**poses)

    def __getattr__(self, key: str) -> Pose:
        """A pose by its key in the file, `above_<option>` or `press_<option>`."""
        kind, _, name = key.partition("_")
        if kind in KINDS:
            for box, above, press in object.__getattribute__(self, "boxes"):
                if box == name:
                    return above if kind == "above" else press
        raise AttributeError(f"{type(self).__name__} has no pose {key!r}")

    @property
    def calibrated(self) -> bool:
        """Whether the poses were recorded."""
        return len(self.home) > 0

    @property
    def names(self) -> tuple[str, ...]:
        """The options with poses, in the order recorded."""
        return tuple(name for name, _, _ in self.boxes)

    def table(self) -> dict[str, Pose]:
        """Every pose by its key in the file, in the order calibration records them."""
        poses = {"home": self.home}
        for name, above, press in self.boxes:
            poses[f"above_{name}"], poses[f"press_{name}"] = above, press
        return poses

    def above(self, name: str) -> Pose:
        """The hover pose over an option's buzzer."""
        return self.select((name,)).boxes[0][1]

    def pressed(self, name: str) -> Pose:
        """The pose pressing an option's buzzer."""
        return self.select((name,)).boxes[0][2]

    def select(self, names: Iterable[str]) -> ArmPoses:
        """The poses of these options, box j for names[j] (ValueError naming those without)."""
        wanted = tuple(names)
        have = {name: (above, press) for name, above, press in self.boxes}
        missing = [name for name in wanted if name not in have]
        if missing:
            raise ValueError(
                f"the arm file has no press pose for option(s) {', '.join(missing)} (it has "
                f"{', '.join(self.names) or 'none'}); record them with `nod actuation calibrate "
                f"--names {','.join(wanted)}`"
            )
        picked = ArmPoses.__new__(ArmPoses)
        object.__setattr__(picked, "home", self.home)
        object.__setattr__(picked, "boxes", tuple((n, *have[n]) for n in wanted))
        return picked


def pose_distance(a: Pose, b: Pose) -> int:
    """The largest difference of one joint between two poses (servo steps, Chebyshev)."""
    return max((abs(x - y) for x, y in zip(a, b, strict=True)), default=0)


def _lerp(a: Pose, b: Pose, u: float) -> tuple[float, ...]:
    return tuple(x + (y - x) * u for x, y in zip(a, b, strict=True))


def pose_on(poses: ArmPoses, box: int, u: float, d: float) -> Pose:
    """Joint goals on box `box`'s spoke at u ∈ [0, 1] and descent d ∈ [0, 1], in steps."""
    _, above, down = poses.boxes[box]
    row = _lerp(poses.home, above, u)
    if d > 0:  # descent only happens at u = 1
        row = tuple(r + (q - a) * d for r, a, q in zip(row, above, down, strict=True))
    return tuple(round(v) for v in row)


def _project(p: Pose, a: Pose, b: Pose) -> tuple[float, float]:
    """(u ∈ [0, 1], squared distance) of the point of segment a→b nearest to p."""
    ab = [y - x for x, y in zip(a, b, strict=True)]
    norm = sum(v * v for v in ab)
    u = 0.0 if norm == 0 else sum((q - x) * v for q, x, v in zip(p, a, ab, strict=True)) / norm
    u = min(max(u, 0.0), 1.0)
    return u, sum((q - w) ** 2 for q, w in zip(p, _lerp(a, b, u), strict=True))


def locate_on(poses: ArmPoses, present: Pose) -> tuple[int, float, float]:
    """(box, u, d) of the path point nearest to the present joints (after a (re)connect).

    An exact tie goes to the first: the lower box, its spoke before its descent.
    """
    best, place = math.inf, (0, 0.0, 0.0)
    for box, (_, above, down) in enumerate(poses.boxes):
        u, dist = _project(present, poses.home, above)
        if dist < best:
            best, place = dist, (box, u, 0.0)
        d, dist = _project(present, above, down)
        if dist < best:
            best, place = dist, (box, 1.0, d)
    return place


def _paper(poses: ArmPoses) -> ArmPoses:
    return poses.select(COLOURS)


def pose_at(poses: ArmPoses, s: float, d: float) -> Pose:
    """The paper's path: joint goals at s ∈ [−1, 1] (> 0 toward red) and descent d ∈ [0, 1]."""
    return pose_on(_paper(poses), 0 if s >= 0 else 1, abs(s), d)


def locate(poses: ArmPoses, present: Pose) -> tuple[float, float]:
    """The paper's (s, d) of the path point nearest to the present joint positions."""
    box, u, d = locate_on(_paper(poses), present)
    return (u if box == 0 else -u), d
