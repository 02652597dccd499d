"""Gaze → servo angles and pulse widths, with limits (SPEC §5).

Each eyeball has a pan and a tilt micro-servo with 180° travel (±90° from the 90° centre):

    angle = 90° + direction · degrees(gaze angle) + trim,   clamped to [min_deg, max_deg]
    pulse = min_pulse_us + angle / 180° · (max_pulse_us − min_pulse_us)

Pan servos follow yaw, tilt servos follow pitch; both eyes move in unison. A command outside the
calibrated limits is clamped and the clamped servos are named in the result: nothing outside the
limits ever reaches a driver.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from services.model.gaze import GazeCommand

SERVO_NAMES: tuple[str, str, str, str] = ("left_pan", "left_tilt", "right_pan", "right_tilt")


@dataclass(frozen=True, slots=True)
class ServoCalibration:
    """One servo's mounting and limits."""

    # Offset added to the angle (deg) so that a zero gaze looks straight ahead.
    trim_deg: float = 0.0
    # +1 or −1: −1 when the servo is mounted mirrored (positive gaze = smaller servo angle).
    direction: int = 1
    # Lowest allowed servo angle (deg), within [0, 180]; the mechanical/safe limit.
    min_deg: float = 0.0
    # Highest allowed servo angle (deg), within [0, 180], > min_deg.
    max_deg: float = 180.0
    # Pulse width at 0° (µs); > 0.
    min_pulse_us: float = 500.0
    # Pulse width at 180° (µs); > min_pulse_us.
    max_pulse_us: float = 2500.0

    def __post_init__(self) -> None:
        for name in ("trim_deg", "min_deg", "max_deg", "min_pulse_us", "max_pulse_us"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"ServoCalibration.{name} must be finite")
        if self.direction not in (1, -1) or isinstance(self.direction, bool):
            raise ValueError(f"ServoCalibration.direction must be +1 or -1, got {self.direction!r}")
        if not 0.0 <= self.min_deg < self.max_deg <= 180.0:
            raise ValueError(
                f"ServoCalibration limits must satisfy 0 <= min_deg < max_deg <= 180, got "
                f"[{self.min_deg}, {self.max_deg}]"
            )
        if not 0.0 < self.min_pulse_us < self.max_pulse_us:
            raise ValueError(
                f"ServoCalibration pulses must satisfy 0 < min_pulse_us < max_pulse_us, got "
                f"[{self.min_pulse_us}, {self.max_pulse_us}]"
            )

    def pulse_us(self, angle_deg: float) -> float:
        """The pulse width (µs) for a servo angle (deg), linear over 0–180°."""
        return self.min_pulse_us + angle_deg / 180.0 * (self.max_pulse_us - self.min_pulse_us)

    @property
    def pulse_limits_us(self) -> tuple[float, float]:
        """The pulse widths (µs) at min_deg and max_deg: every pulse sent lies in between."""
        return self.pulse_us(self.min_deg), self.pulse_us(self.max_deg)


@dataclass(frozen=True, slots=True)
class EyesCalibration:
    """The four servos of the two eyeballs."""

    left_pan: ServoCalibration = field(default_factory=ServoCalibration)
    left_tilt: ServoCalibration = field(default_factory=ServoCalibration)
    right_pan: ServoCalibration = field(default_factory=ServoCalibration)
    right_tilt: ServoCalibration = field(default_factory=ServoCalibration)

    def servos(self) -> tuple[ServoCalibration, ...]:
        """The calibrations in `SERVO_NAMES` order."""
        return (self.left_pan, self.left_tilt, self.right_pan, self.right_tilt)


@dataclass(frozen=True, slots=True)
class ServoTargets:
    """Angles and pulses for the four servos, in `SERVO_NAMES` order, and what was clamped."""

    angles_deg: tuple[float, float, float, float]
    pulses_us: tuple[float, float, float, float]
    clamped: tuple[str, ...] = ()  # names of servos whose commanded angle was out of limits

    def __post_init__(self) -> None:
        if len(self.angles_deg) != 4 or len(self.pulses_us) != 4:
            raise ValueError("ServoTargets needs exactly 4 angles and 4 pulses")
        if not all(math.isfinite(v) for v in (*self.angles_deg, *self.pulses_us)):
            raise ValueError(f"ServoTargets must be finite, got {self}")
        unknown = set(self.clamped) - set(SERVO_NAMES)
        if unknown:
            raise ValueError(f"unknown servo name(s) {sorted(unknown)}; expected {SERVO_NAMES}")

    def as_dict(self) -> dict[str, tuple[float, float]]:
        """{servo name: (angle deg, pulse µs)}."""
        return {
            n: (a, p) for n, a, p in zip(SERVO_NAMES, self.angles_deg, self.pulses_us, strict=True)
        }


def requested_angle(angle_rad: float, c: ServoCalibration) -> float:
    """The servo angle (deg) a gaze angle asks for, before clamping: may lie outside the limits.

    math.degrees of a huge finite angle is ±inf; clamping handles it like any other overshoot.
    """
    return 90.0 + c.direction * math.degrees(angle_rad) + c.trim_deg


def requested_angles(cmd: GazeCommand, calib: EyesCalibration) -> tuple[float, ...]:
    """The four unclamped servo angles (deg) of a gaze, in `SERVO_NAMES` order (for reports)."""
    gaze_angles = (cmd.yaw, cmd.pitch, cmd.yaw, cmd.pitch)  # pan ← yaw, tilt ← pitch
    return tuple(requested_angle(g, c) for g, c in zip(gaze_angles, calib.servos(), strict=True))


def _servo(angle_rad: float, c: ServoCalibration) -> tuple[float, float, bool]:
    raw = requested_angle(angle_rad, c)
    angle = min(max(raw, c.min_deg), c.max_deg)
    return angle, c.pulse_us(angle), angle != raw


def servo_targets(cmd: GazeCommand, calib: EyesCalibration) -> ServoTargets:
    """The four servo targets for a gaze, clamped to the calibrated limits."""
    angles: list[float] = []
    pulses: list[float] = []
    clamped: list[str] = []
    gaze_angles = (cmd.yaw, cmd.pitch, cmd.yaw, cmd.pitch)  # pan ← yaw, tilt ← pitch
    for name, g, c in zip(SERVO_NAMES, gaze_angles, calib.servos(), strict=True):
        angle, pulse, was_clamped = _servo(g, c)
        angles.append(angle)
        pulses.append(pulse)
        if was_clamped:
            clamped.append(name)
    return ServoTargets(
        (angles[0], angles[1], angles[2], angles[3]),
        (pulses[0], pulses[1], pulses[2], pulses[3]),
        tuple(clamped),
    )


def enforce_limits(targets: ServoTargets, calib: EyesCalibration) -> ServoTargets:
    """Re-clamp targets to the calibration (drivers call this: never trust a caller's targets).

    Pulses are recomputed from the clamped angles, so a hand-built inconsistent target cannot
    slip a raw pulse through. Newly clamped servos are added to `clamped`.
    """
    angles: list[float] = []
    pulses: list[float] = []
    clamped = list(targets.clamped)
    for name, a, c in zip(SERVO_NAMES, targets.angles_deg, calib.servos(), strict=True):
        angle = min(max(a, c.min_deg), c.max_deg)
        if angle != a and name not in clamped:
            clamped.append(name)
        angles.append(angle)
        pulses.append(c.pulse_us(angle))
    return ServoTargets(
        (angles[0], angles[1], angles[2], angles[3]),
        (pulses[0], pulses[1], pulses[2], pulses[3]),
        tuple(n for n in SERVO_NAMES if n in clamped),
    )
