"""The observed human opinion over N_o boxes: eq 7 as an N_o-vector (docs/multi-option.md).

The robust observer's reading (`services.model.observer_robust`), over any number of boxes:

- the hand centre (mean of the landmarks) is smoothed with time constant `smooth_s`, and its
  movement M is the smoothed centre's displacement over the last `window_s` seconds;
- θ_j is the angle between M and the bearing from the hand to box j's centre; the target is
  the box M points at most directly;
- M slower than `min_speed`, or further than `max_angle_deg` from every box's bearing: the
  hand heads for none, ẑ_h is held;
- the reading leaves the current box only for one M points at by `switch_margin` (in cos θ)
  more directly: jitter between two nearly equal bearings is not a change of mind. The margin
  is capped at `neighbour_share` (½) of 1 − cos φ, φ the angle between the two boxes' bearings
  from the hand: neighbours in a row of three or more boxes are only ~24° apart from where the
  hand starts (1 − cos φ ≈ 0.08 < 0.15), and a fixed margin would hold the old reading until
  the hand nears the boxes (docs/multi-option.md has the numbers);
- ẑ_h = a · cos θ · tanh(k / d) · option_vector(target): eq 7's magnitude along the target's
  zero-sum direction, so target j leads every other option by 2 a cos θ tanh(k/d).

With the two boxes of a `TableLayout` (option 0 = red, 1 = blue) and `neighbour_share=None`
ẑ_h is exactly (z, −z) for the robust observer's z. The reading is categorical on purpose: a
vector graded by every box's cos θ_j would let jitter move the argmax between neighbouring
boxes, whose bearings are closer with more boxes on the same table edge.

Pure: time (s) is passed in with each pose. The boxes are an `OptionsLayout`
(`services.model.geometry`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from services.model.dynamics import option_vector
from services.model.geometry import OptionsLayout, Point
from services.model.observer import ObserverParams, hand_center
from services.model.observer_robust import MotionWindow

# The switch margin is capped at this share of the cos gap between two boxes' bearings
NEIGHBOUR_SHARE = 0.5

@dataclass(frozen=True, slots=True)
class OptionsObservation:
    """What the observer read from one pose: ẑ_h (held unless `moved`), target, θ, d."""

    z_hat: np.ndarray
    center: Point | None
    target: int | None  # the box this pose read, None unless it gave a direction
    theta: float | None
    distance: float | None
    moved: bool
    detected: bool


class OptionsObserver:
    """ẑ_h over N_o boxes from hand poses (see module doc); the robust ObserverParams apply."""

    def __init__(
        self,
        layout: OptionsLayout,
        params: ObserverParams | None = None,
        neighbour_share: float | None = NEIGHBOUR_SHARE,
    ):
        if neighbour_share is not None and not 0 < neighbour_share <= 1:
            raise ValueError(f"neighbour_share must be in (0, 1] or None, got {neighbour_share}")
        self._params = params if params is not None else ObserverParams()
        self._layout = layout
        self._share = neighbour_share
        self._cos_min = math.cos(math.radians(self._params.max_angle_deg))
        self._motion = MotionWindow(self._params.smooth_s, self._params.window_s)
        self.reset()

    @property
    def layout(self) -> OptionsLayout:
        """The boxes the hand is read against."""
        return self._layout

    @property
    def z_hat(self) -> np.ndarray:
        """The current ẑ_h (zero before any movement it could read); a copy."""
        return self._z_hat.copy()

    @property
    def target(self) -> int | None:
        """The box of the current reading (None before the first)."""
        return self._target

    def reset(self) -> None:
        """Forget all history: ẑ_h = 0, no target, an empty window."""
        self._z_hat = np.zeros(self._layout.n_options)
        self._target: int | None = None
        self._motion.reset()

    def update(self, landmarks: Sequence[Point] | None, t: float = 0.0) -> OptionsObservation:
        """Read one pose at time t (s): the landmarks of one hand, or None when none was seen."""
        if not landmarks:
            return OptionsObservation(self.z_hat, None, None, None, None, False, False)
        center = hand_center(landmarks)
        window = self._motion.add(center, t)
        reading = None
        if window is not None:
            here, movement, span = window
            length = math.hypot(*movement)
            if length >= self._params.min_speed * span:
                reading = self._read(here, movement, length)
        if reading is None:
            return OptionsObservation(self.z_hat, center, None, None, None, False, True)
        target, theta, distance = reading
        p = self._params
        self._target = target
        magnitude = p.a * math.cos(theta) * math.tanh(p.k / distance)
        self._z_hat = magnitude * option_vector(target, self._layout.n_options)
        return OptionsObservation(self.z_hat, center, target, theta, distance, True, True)

    def _read(self, here: Point, movement: Point, length: float) -> tuple[int, float, float] | None:
        """(target, θ, d) if the movement heads for a box, else None."""
        d_min = self._params.d_min
        cosines: list[float] = []
        dists: list[float] = []
        bearings: list[Point] = []
        for j, box in enumerate(self._layout.boxes):
            bx, by = box.center[0] - here[0], box.center[1] - here[1]
            dist = math.hypot(bx, by)
            if dist < d_min:  # on the box: it is the target, head-on
                return j, 0.0, d_min
            cosines.append((movement[0] * bx + movement[1] * by) / (length * dist))
            dists.append(dist)
            bearings.append((bx / dist, by / dist))
        best = max(range(len(cosines)), key=cosines.__getitem__)
        current = self._target
        if current is not None and best != current:
            margin = self._params.switch_margin
            if self._share is not None:
                # The most a movement can favour `best` over `current` is 1 − cos φ, φ the angle
                # between their bearings: a margin above that would forbid the switch until
                # the hand is near the boxes. Neighbours in a row of boxes are that close.
                (ax, ay), (cx, cy) = bearings[best], bearings[current]
                margin = min(margin, self._share * (1.0 - (ax * cx + ay * cy)))
            if cosines[best] - cosines[current] < margin:
                best = current  # not clearly another box: stay with the current reading
        if cosines[best] < self._cos_min:
            return None  # heading for no box
        theta = math.acos(max(-1.0, min(1.0, cosines[best])))
        return best, theta, max(dists[best], d_min)
