"""Observed human opinion from hand motion (paper eq 7, Algorithm 1, SPEC §2).

    ẑ_h = a · cos θ · tanh(k / d)                                      (eq 7)

θ is the direction of the hand's movement M = p(t) − p(t−1) (image x right, y down, so the
angle uses −M_y), folded into [0, π); d is the distance from the hand centre to the anchor of the
buzzer that θ points at. Sign convention: ẑ_h > 0 ⇔ red, ẑ_h < 0 ⇔ blue.

Two properties of Algorithm 1 worth knowing when reading the output:
- The fold θ ← θ − π on [π, 2π) is a point reflection, so M and −M read the same: a hand moving
  back toward the participant reads as heading for the opposite side. Red ⇔ M_x and −M_y share
  a sign (after mirroring), so a near-horizontal movement flips between ±a with the sign of a
  tiny vertical component.
- θ is measured against the image x axis, not the bearing to a box: a hand heading for the red
  anchor reads red only when it approaches from the blue side of that anchor.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, NamedTuple

from services.model.checks import require_finite, require_non_negative, require_positive
from services.model.geometry import Colour, Point, TableLayout

_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi


@dataclass(frozen=True, slots=True)
class ObserverParams:
    """Parameters of the human-opinion observer (eq 7, Sec 4.6 defaults, SPEC §2).

    `mode` picks how the movement's direction is read. "robust" (the default,
    `services.model.observer_robust`): a lightly smoothed centre, its motion over `window_s`,
    the angle to the bearing of each box; held when heading for neither. "paper": Algorithm 1
    as printed (frame-to-frame motion, θ against the image x axis), for replication. Both use
    eq 7 with `a`, `k`, `d_min`. The numbers behind the robust defaults (wrong-side frames,
    spurious switches and latency on jittery paths at 30 and 60 Hz) are in docs/observer.md.
    """

    mode: Literal["robust", "paper"] = "robust"
    a: float = 8.0  # directional-intent gain; bounds |ẑ_h| ≤ a
    k: float = 1.5  # distance scale of tanh(k/d), in normalised image units
    noise_threshold: float = 0.002  # per-frame movement below which θ is undefined (norm. units)
    anchor: Literal["corner", "center"] = "corner"  # box point d is measured to (Algorithm 1)
    d_min: float = 1e-6  # lower clamp of d, keeps k/d finite at the anchor
    # Where M is measured from. "frame": the previous frame's centre (Algorithm 1). "accepted": the
    # centre at which θ was last defined, so movements slower than noise_threshold per frame
    # still add up; makes the threshold a distance rather than a speed that depends on frame rate.
    reference: Literal["frame", "accepted"] = "frame"
    # -- robust mode ---------------------------------------------------------------------------
    smooth_s: float = 0.06  # time constant of the centre's exponential smoothing (s); ≥ 0
    window_s: float = 0.12  # motion is measured over this much time (s), whatever the frame rate
    min_speed: float = 0.10  # below this speed over the window (units/s) no direction: ẑ_h held
    max_angle_deg: float = 55.0  # a heading further than this from both boxes' bearings: held
    switch_margin: float = 0.15  # cos advantage the other box needs to take over the reading
    # |ẑ_h| at or below this carries no side for the switch count (a hesitant, sideways or
    # stopped hand must not count as a change of mind); robust mode only (the paper counts
    # every sign change)
    dead_band: float = 0.5

    @property
    def switch_dead_band(self) -> float:
        """The dead band the switch count applies: `dead_band`, or 0 in paper mode."""
        return self.dead_band if self.mode == "robust" else 0.0

    def __post_init__(self) -> None:
        if self.mode not in ("robust", "paper"):
            raise ValueError(f"ObserverParams.mode must be 'robust' or 'paper', not {self.mode!r}")
        require_non_negative(
            self, "smooth_s", "window_s", "min_speed", "max_angle_deg", "switch_margin", "dead_band"
        )
        if not 0 < self.window_s <= 2.0 or not 0 < self.max_angle_deg < 90:
            raise ValueError(
                "ObserverParams.window_s must be in (0, 2] s and max_angle_deg in (0, 90)"
            )
        require_finite(self, "a", "k", "noise_threshold", "d_min")
        require_positive(self, "a", "k", "d_min")
        require_non_negative(self, "noise_threshold")
        if self.anchor not in ("corner", "center"):
            raise ValueError(
                f"ObserverParams.anchor must be 'corner' or 'center', not {self.anchor!r}"
            )
        if self.reference not in ("frame", "accepted"):
            raise ValueError(
                f"ObserverParams.reference must be 'frame' or 'accepted', not {self.reference!r}"
            )


class Observation(NamedTuple):
    """What the observer read from one hand pose (a NamedTuple: built once per camera frame).

    `z_hat` is the observed opinion after this pose (held from earlier poses when this one gives
    no direction). `center`/`movement` are None when no hand was detected (stale == not
    detected); `theta`/`target`/`distance` are None unless this pose defined a direction.
    """

    z_hat: float
    center: Point | None
    movement: Point | None  # M, as measured in the image (before any layout mirroring)
    theta: float | None  # folded angle in [0, π), after mirroring
    target: Colour | None
    distance: float | None
    moved: bool  # ‖M‖ ≥ noise_threshold: this pose set a new ẑ_h
    detected: bool


def anchor_point(layout: TableLayout, colour: Colour, anchor: Literal["corner", "center"]) -> Point:
    """The point of a buzzer box that d is measured to (Algorithm 1 uses the first corner)."""
    box = layout.box(colour)
    return box.corner if anchor == "corner" else box.center


def fold_theta(m_x: float, m_y: float) -> float:
    """θ = atan2(−M_y, M_x) wrapped to [0, 2π), then [π, 2π) shifted by −π (Algorithm 1).

    Both branches of Algorithm 1 (θ ← π − (2π − θ) on [3π/2, 2π), θ ← θ − π on [π, 3π/2))
    reduce to θ − π, so the result lies in [0, π).
    """
    theta = math.atan2(-m_y, m_x) % _TWO_PI
    # A tiny negative angle wraps to exactly 2π in floating point; it means 0.
    if theta >= _TWO_PI:
        theta = 0.0
    if theta >= math.pi:
        theta -= math.pi
    return theta


def observe_movement(
    prev: Point, cur: Point, layout: TableLayout, params: ObserverParams
) -> tuple[float, Colour, float, float] | None:
    """Eq 7 for one movement prev → cur: (θ, target, d, ẑ_h), or None when ‖M‖ < threshold.

    Below the noise threshold atan2 of (almost) zero would read as a confident direction
    (atan2(0, 0) = 0 is full red), so the direction is declared undefined instead (SPEC §2).
    """
    m_x = cur[0] - prev[0]
    m_y = cur[1] - prev[1]
    if math.hypot(m_x, m_y) < params.noise_threshold or (m_x == 0.0 and m_y == 0.0):
        return None
    # Algorithm 1 assumes red toward +x; mirroring M_x keeps "θ < π/2 ⇔ red" for either layout.
    if not layout.red_on_right:
        m_x = -m_x
    theta = fold_theta(m_x, m_y)
    target: Colour = "red" if theta < _HALF_PI else "blue"
    ax, ay = anchor_point(layout, target, params.anchor)
    distance = max(math.hypot(cur[0] - ax, cur[1] - ay), params.d_min)
    z_hat = params.a * math.cos(theta) * math.tanh(params.k / distance)
    return theta, target, distance, z_hat


def hand_center(landmarks: Sequence[Point]) -> Point:
    """Mean of the landmarks (Algorithm 1's p(t)); any count ≥ 1."""
    n = len(landmarks)
    sx = 0.0
    sy = 0.0
    for x, y in landmarks:
        sx += x
        sy += y
    return (sx / n, sy / n)


class ObserverBase:
    """What both readings of eq 7 share: parameters, table layout, ẑ_h, the latest observation."""

    def __init__(self, params: ObserverParams | None = None, layout: TableLayout | None = None):
        self._params = params if params is not None else ObserverParams()
        self._layout = layout if layout is not None else TableLayout()
        self._z_hat = 0.0
        self._last: Observation | None = None

    @property
    def params(self) -> ObserverParams:
        """The observer's parameters."""
        return self._params

    @property
    def layout(self) -> TableLayout:
        """The table layout: mirroring, the boxes' bearings and distances."""
        return self._layout

    @layout.setter
    def layout(self, layout: TableLayout) -> None:
        # Keeps ẑ_h and the motion history: the layout only changes how later poses read.
        self._layout = layout

    @property
    def z_hat(self) -> float:
        """The current observed opinion ẑ_h (0 before any movement it could read)."""
        return self._z_hat

    @property
    def last(self) -> Observation | None:
        """The observation returned by the latest `update`, or None after `reset`."""
        return self._last

    def _report(self, obs: Observation) -> Observation:
        """Keep `obs` as `last` and return it: every reading of a pose ends here."""
        self._last = obs
        return obs

    def _no_hand(self) -> Observation:
        """A pose with no hand: ẑ_h held, nothing measured (stale == not detected)."""
        return self._report(Observation(self._z_hat, None, None, None, None, None, False, False))

    def _hold(self, center: Point, movement: Point | None) -> Observation:
        """A hand seen but no direction read from it (yet): ẑ_h held."""
        obs = Observation(self._z_hat, center, movement, None, None, None, False, True)
        return self._report(obs)


class PaperObserver(ObserverBase):
    """Algorithm 1 as printed (the "paper" mode): feed it one hand pose per camera frame."""

    def __init__(self, params: ObserverParams | None = None, layout: TableLayout | None = None):
        super().__init__(params, layout)
        self._reference: Point | None = None  # where the next M is measured from

    def reset(self) -> None:
        """Forget all history: ẑ_h = 0 and the next pose is a first frame."""
        self._z_hat = 0.0
        self._reference = None
        self._last = None

    def update(self, landmarks: Sequence[Point] | None, t: float = 0.0) -> Observation:
        """Read one pose: the landmarks of one hand, or None/empty when no hand was detected.

        Algorithm 1 reads frame to frame: the time `t` (s) is not used.
        """
        if not landmarks:
            # Stale: keep ẑ_h and the reference, so the next detection's M is measured from the
            # last centre seen rather than reading a jump from nowhere.
            return self._no_hand()
        center = hand_center(landmarks)
        prev = self._reference
        if prev is None:
            # First frame: no movement yet, ẑ_h stays 0 (SPEC §2).
            self._reference = center
            return self._hold(center, None)
        movement = (center[0] - prev[0], center[1] - prev[1])
        reading = observe_movement(prev, center, self._layout, self._params)
        if reading is None:
            if self._params.reference == "frame":
                self._reference = center
            return self._hold(center, movement)
        theta, target, distance, z_hat = reading
        self._z_hat = z_hat
        self._reference = center
        return self._report(
            Observation(z_hat, center, movement, theta, target, distance, True, True)
        )

