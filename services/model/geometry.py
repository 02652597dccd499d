"""Table geometry shared by every service: the buzzer boxes and the decision commit line.

The paper's table is `TableLayout` (a red and a blue box); a table of N_o options is
`OptionsLayout` (a box per option; option 0 is red on the paper's table, `from_table`).

Coordinates are normalised image coordinates: x to the right, y down, both in [0, 1] (SPEC §2).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Literal, TypeAlias

import numpy as np

Point: TypeAlias = tuple[float, float]
Colour: TypeAlias = Literal["red", "blue"]
COLOURS: tuple[Colour, Colour] = ("red", "blue")

# A flat right hand seen from above, fingers toward −y (the buzzers), in units of the hand
# radius; MediaPipe order: wrist, thumb CMC..tip, index MCP..tip, middle, ring, little. The one
# hand shape of the project: the simulated participant's landmarks, the rendered camera's hand
# and the `sim` tracker's pose all use it.
_HAND = np.array(
    [(0.0, 0.9)]
    + [(-0.35, 0.6), (-0.6, 0.35), (-0.8, 0.1), (-0.95, -0.1)]
    + [(-0.32, -0.25), (-0.34, -0.6), (-0.36, -0.85), (-0.38, -1.05)]
    + [(-0.05, -0.3), (-0.05, -0.7), (-0.05, -0.97), (-0.05, -1.2)]
    + [(0.2, -0.25), (0.23, -0.62), (0.25, -0.88), (0.27, -1.08)]
    + [(0.42, -0.15), (0.5, -0.42), (0.55, -0.62), (0.6, -0.8)]
)
HAND_TEMPLATE: np.ndarray = _HAND - _HAND.mean(axis=0)  # zero mean: centre = mean of landmarks
HAND_TEMPLATE.setflags(write=False)


def colour_sign(colour: Colour) -> int:
    """+1 for red, −1 for blue: the sign convention of every opinion (SPEC)."""
    return 1 if colour == "red" else -1


def sign_colour(sign: float) -> Colour | None:
    """The colour a signed opinion points to, or None for exactly zero."""
    if sign > 0:
        return "red"
    if sign < 0:
        return "blue"
    return None


TIE = 1e-9  # distances closer than this are equal (float rounding, not geometry)


@dataclass(frozen=True, slots=True)
class Box:
    """An axis-aligned box given by two corners (x1, y1) and (x2, y2), x1 ≤ x2 and y1 ≤ y2.

    The first corner is Algorithm 1's distance anchor (`p_buzzer[c][0]`).
    """

    x1: float
    y1: float
    x2: float
    y2: float

    def __post_init__(self) -> None:
        values = (self.x1, self.y1, self.x2, self.y2)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"box corners must be finite, got {values}")
        if self.x1 > self.x2 or self.y1 > self.y2:
            raise ValueError(f"box corners must satisfy x1 <= x2 and y1 <= y2, got {values}")

    @property
    def corner(self) -> Point:
        """The first corner (x1, y1)."""
        return (self.x1, self.y1)

    @property
    def center(self) -> Point:
        """The centre of the box."""
        return ((self.x1 + self.x2) / 2.0, (self.y1 + self.y2) / 2.0)

    def contains(self, p: Point) -> bool:
        """Whether a point lies inside the box, edges included (Algorithm 2's press test)."""
        return self.x1 <= p[0] <= self.x2 and self.y1 <= p[1] <= self.y2


@dataclass(frozen=True, slots=True)
class CommitLine:
    """The decision commit line, as a horizontal image line y = const.

    The hand starts on the participant's side (`start_side` = "below" when the participant stands
    at the bottom of the image, larger y) and crosses the line on its way to the buzzers.
    """

    y: float = 0.45
    start_side: Literal["below", "above"] = "below"

    def crossed(self, p: Point) -> bool:
        """Whether a hand position lies past the line, on the buzzers' side."""
        return p[1] < self.y if self.start_side == "below" else p[1] > self.y


@dataclass(frozen=True, slots=True)
class TableLayout:
    """The two buzzer boxes and the commit line, as seen by the overhead camera."""

    red: Box = field(default_factory=lambda: Box(0.72, 0.12, 0.86, 0.26))
    blue: Box = field(default_factory=lambda: Box(0.14, 0.12, 0.28, 0.26))
    commit: CommitLine = field(default_factory=CommitLine)

    def box(self, colour: Colour) -> Box:
        """The box of one buzzer."""
        return self.red if colour == "red" else self.blue

    @property
    def red_on_right(self) -> bool:
        """Algorithm 1 assumes red toward +x; False means the layout is mirrored (SPEC §2)."""
        return self.red.center[0] >= self.blue.center[0]

    def pressed(self, points: Iterable[Point]) -> Colour | None:
        """The buzzer whose box holds any of the points (a hand landmark), or None."""
        for p in points:
            for colour in COLOURS:
                if self.box(colour).contains(p):
                    return colour
        return None

    def nearest(self, p: Point) -> Colour:
        """The buzzer whose box centre is nearest to p (ties go to red, as Algorithm 2).

        Deviation: Algorithm 2 measures to each box's first corner, which with both corners on
        the boxes' left edges biases a robot standing midway toward red; the centre is what
        "the buzzer nearest to the end effector" means physically and is symmetric.
        """
        d_red = math.dist(p, self.red.center)
        d_blue = math.dist(p, self.blue.center)
        # A tie is a tie within rounding: the default boxes' centres come out 0.79 and
        # 0.21000000000000002, which put the arm's home, midway, 1 ulp nearer blue.
        return "blue" if d_blue < d_red - TIE else "red"


# The paper's table edge: the two-option boxes span x 0.14-0.86 at y 0.12-0.26 (geometry.py).
_EDGE = (0.21, 0.79)  # the outer boxes' centres
_Y = (0.12, 0.26)
_WIDTH = 0.14


@dataclass(frozen=True, slots=True)
class OptionsLayout:
    """The table over N_o options: a box per option (`boxes[j]`) and the commit line."""

    boxes: tuple[Box, ...]
    commit: CommitLine = field(default_factory=CommitLine)

    def __post_init__(self) -> None:
        if len(self.boxes) < 2:
            raise ValueError(f"a layout needs at least 2 boxes, got {len(self.boxes)}")

    @property
    def n_options(self) -> int:
        """How many boxes (options) the table has."""
        return len(self.boxes)

    @classmethod
    def row(cls, n_options: int) -> OptionsLayout:
        """N_o boxes in a row on the paper's far table edge, left to right, equally spaced.

        Each is the paper's 0.14 wide, narrowed to 90 % of the spacing when they would touch.
        """
        if n_options < 2:
            raise ValueError(f"a layout needs at least 2 boxes, got {n_options}")
        centres = np.linspace(_EDGE[0], _EDGE[1], n_options)
        half = 0.5 * min(_WIDTH, 0.9 * (centres[1] - centres[0]))
        return cls(tuple(Box(float(c - half), _Y[0], float(c + half), _Y[1]) for c in centres))

    @classmethod
    def from_table(cls, layout: TableLayout) -> OptionsLayout:
        """The two-option table as options (red, blue): option 0 is red, as z > 0 is."""
        return cls((layout.red, layout.blue), layout.commit)

    def nearest(self, p: Point) -> int:
        """The option whose box centre is nearest to p (Algorithm 2's press).

        A tie (within `TIE`) goes to the lower index, as `TableLayout.nearest` gives it to red.
        """
        best, best_d = 0, math.dist(p, self.boxes[0].center)
        for j in range(1, len(self.boxes)):
            d = math.dist(p, self.boxes[j].center)
            if d < best_d - TIE:
                best, best_d = j, d
        return best

    def pressed(self, points: Iterable[Point]) -> int | None:
        """The option whose box holds any of the points (a hand landmark), or None."""
        for p in points:
            for j, box in enumerate(self.boxes):
                if box.contains(p):
                    return j
        return None
