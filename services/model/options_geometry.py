"""The table over N_o options: a box per option and the commit line (docs/multi-option.md).

Normalised image coordinates, x right, y down, as `services.model.geometry`. Option j's box is
`boxes[j]`; on the paper's table option 0 is red and option 1 blue (`from_table`), so the
two-option sign convention (z > 0 ⇔ red) is option 0 leading.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from services.model.geometry import TIE, Box, CommitLine, Point, TableLayout

# The paper's table edge: the two-option boxes span x 0.14-0.86 at y 0.12-0.26 (geometry.py).
_EDGE = (0.21, 0.79)  # the outer boxes' centres
_Y = (0.12, 0.26)
_WIDTH = 0.14


@dataclass(frozen=True, slots=True)
class OptionsLayout:
    """N_o boxes (option j's box is `boxes[j]`) and the commit line, as the camera sees them."""

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
