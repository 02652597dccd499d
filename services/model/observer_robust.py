"""The robust reading of the human opinion (eq 7 with a steadier θ): the default observer.

Algorithm 1 reads the direction of the hand frame to frame against the image x axis. With a
real camera's jitter that direction is mostly noise (a 1-3 px jitter reads the wrong side in
9-86% of frames of ordinary reaches, worse at 60 Hz), a hand drawing back reads as heading for
the other box, and a still hand's θ is undefined. This observer keeps eq 7,

    ẑ_h = ± a · cos θ · tanh(k / d),

and reads θ and the target differently:

- the centre (mean of the landmarks) is smoothed with a time constant `smooth_s`;
- the movement M is the smoothed centre's displacement over the last `window_s` seconds, so
  the reading does not depend on the frame rate;
- θ is the angle between M and the bearing from the hand to each box's centre; the target is
  the box M points at more directly, and θ its angle (cos θ > 0 always);
- when M is slower than `min_speed`, or points further than `max_angle_deg` from both boxes
  (drawing back, sideways, still), the hand heads for neither: ẑ_h is held;
- the reading moves to the other box only when M points at it by `switch_margin` (in cos θ)
  more directly than at the current one: jitter between two nearly equal bearings is not a
  change of mind;
- d is the distance to the target box's centre.

**Over N_o boxes** (`OptionsObserver`, docs/multi-option.md): the same reading against every
box's bearing, ẑ_h = a · cos θ · tanh(k / d) · option_vector(target), an N_o-vector (target j
leads every other option by 2 a cos θ tanh(k/d)). The reading leaves the current box only for
one M points at by `switch_margin` more directly, that margin capped at `neighbour_share` (½)
of 1 − cos φ, φ the angle between the two boxes' bearings from the hand: neighbours in a row of
three or more boxes are only ~24° apart from where the hand starts (1 − cos φ ≈ 0.08 < 0.15),
and a fixed margin would hold the old reading until the hand nears the boxes. With the two
boxes of a `TableLayout` (option 0 = red, 1 = blue) and `neighbour_share=None` its ẑ_h is
exactly (z, −z) for `RobustObserver`'s z (tests/unit/test_observer_robust.py): `RobustObserver`
is the paper rig's two-box reading, kept as written because the study's golden pins its
arithmetic and its `Observation` (a colour, the movement) is what the paper's services carry.
The reading is categorical on purpose: a vector graded by every box's cos θ_j would let jitter
move the argmax between neighbouring boxes, whose bearings are closer with more boxes.

Pure: time (s) is passed in with each pose.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from services.model.dynamics import option_vector
from services.model.geometry import COLOURS, Colour, OptionsLayout, Point, TableLayout, colour_sign
from services.model.observer import (
    Observation,
    ObserverBase,
    ObserverParams,
    PaperObserver,
    hand_center,
)


class MotionWindow:
    """The smoothed hand centre and its displacement over the last `window_s` seconds.

    The robust reading's motion, shared with the N_o-box observer (`OptionsObserver`).
    """

    def __init__(self, smooth_s: float, window_s: float):
        self._smooth_s, self._window_s = smooth_s, window_s
        self.reset()

    def reset(self) -> None:
        """Forget the centre and the window."""
        self._smooth: Point | None = None
        self._t: float | None = None
        self._trail: deque[tuple[float, Point]] = deque()

    def add(self, center: Point, t: float) -> tuple[Point, Point, float] | None:
        """(smoothed centre, M, span) after one centre at t; None until half a window is seen."""
        if self._smooth is None or self._t is None or t <= self._t:
            smooth = center if self._smooth is None else self._smooth
        else:
            tau = self._smooth_s
            alpha = 1.0 - math.exp(-(t - self._t) / tau) if tau > 0 else 1.0
            smooth = (
                self._smooth[0] + alpha * (center[0] - self._smooth[0]),
                self._smooth[1] + alpha * (center[1] - self._smooth[1]),
            )
        self._smooth, self._t = smooth, t
        trail = self._trail
        trail.append((t, smooth))
        while len(trail) > 2 and trail[1][0] <= t - self._window_s:
            trail.popleft()  # keep one sample at or before the window's start
        t0, start = trail[0]
        span = t - t0
        if span < 0.5 * self._window_s:
            return None
        return smooth, (smooth[0] - start[0], smooth[1] - start[1]), span


class RobustObserver(ObserverBase):
    """Eq 7 on a smoothed, windowed movement against the boxes' bearings (see module doc)."""

    def __init__(self, params: ObserverParams | None = None, layout: TableLayout | None = None):
        super().__init__(params, layout)
        self._cos_min = math.cos(math.radians(self._params.max_angle_deg))
        self._motion = MotionWindow(self._params.smooth_s, self._params.window_s)
        self.reset()

    def reset(self) -> None:
        """Forget all history: ẑ_h = 0, no smoothed centre, an empty window."""
        self._z_hat = 0.0
        self._sign = 0
        self._motion.reset()
        self._last: Observation | None = None

    def update(self, landmarks: Sequence[Point] | None, t: float = 0.0) -> Observation:
        """Read one pose at time t (s): the landmarks of one hand, or None when none was seen."""
        if not landmarks:
            return self._no_hand()
        center = hand_center(landmarks)
        p = self._params
        window = self._motion.add(center, t)
        if window is None:  # not enough history yet for a direction
            return self._hold(center, None)
        smooth, movement, span = window
        length = math.hypot(*movement)
        if length < p.min_speed * span:
            return self._hold(center, movement)
        reading = self._read(smooth, movement, length)
        if reading is None:
            return self._hold(center, movement)
        colour, theta, distance = reading
        sign = colour_sign(colour)
        self._sign = sign
        self._z_hat = sign * p.a * math.cos(theta) * math.tanh(p.k / distance)
        return self._report(
            Observation(self._z_hat, center, movement, theta, colour, distance, True, True)
        )

    def _read(
        self, here: Point, movement: Point, length: float
    ) -> tuple[Colour, float, float] | None:
        """(target, θ, d) if the movement heads for a box, else None."""
        cosines: dict[Colour, tuple[float, float]] = {}
        for colour in COLOURS:
            ax, ay = self._layout.box(colour).center
            bx, by = ax - here[0], ay - here[1]
            dist = math.hypot(bx, by)
            if dist < self._params.d_min:  # on the box: it is the target, head-on
                return colour, 0.0, self._params.d_min
            cosines[colour] = ((movement[0] * bx + movement[1] * by) / (length * dist), dist)
        best: Colour = max(COLOURS, key=lambda c: cosines[c][0])
        other: Colour = "blue" if best == "red" else "red"
        if cosines[best][0] < self._cos_min:
            return None  # heading for neither box
        unclear = cosines[best][0] - cosines[other][0] < self._params.switch_margin
        if self._sign and colour_sign(best) != self._sign and unclear:
            best = other  # not clearly the other box: stay with the current reading
            if cosines[best][0] < self._cos_min:
                return None
        cos_theta, dist = cosines[best]
        theta = math.acos(max(-1.0, min(1.0, cos_theta)))
        return best, theta, max(dist, self._params.d_min)


def make_observer(
    params: ObserverParams | None = None, layout: TableLayout | None = None
) -> PaperObserver | RobustObserver:
    """The observer `params.mode` asks for; both take update(landmarks, t) and hold z_hat."""
    p = params if params is not None else ObserverParams()
    return PaperObserver(p, layout) if p.mode == "paper" else RobustObserver(p, layout)


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
