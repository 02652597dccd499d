"""The eyes' trims file: each servo's centre offset, as `nod eyes calibrate` writes it.

    [trim_deg]           # degrees added to each servo's angle (ServoCalibration.trim_deg)
    left_pan = 1.25
    left_tilt = -0.5
    right_pan = 0.0
    right_tilt = 2.0

`nod eyes --trims FILE` (also `nod eyes point` and `nod eyes calibrate`) lays these over the
calibration in effect — the eyes file's `[calibration]`, else the `--params` file's `[eyes]`,
else the defaults — replacing only `trim_deg`: directions, limits and pulse ranges stay theirs.
A servo left out of the table keeps its trim. The file is checked when it is loaded and again
when it is laid over a calibration; every error is one line naming the file and the key.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

from services.core.config import ConfigError, from_mapping, load_toml
from services.model.servos import SERVO_NAMES, EyesCalibration

# A trim larger than this is not a trim: a 25-tooth servo spline moves the horn 14.4° per tooth,
# so an eye more than ~one tooth off centre should have its horn re-seated, not be trimmed (and
# a trim eats into the travel the gaze levels need on one side).
MAX_TRIM_DEG = 20.0


@dataclass(frozen=True, slots=True)
class EyesTrims:
    """Trim (deg) per servo; None: keep the calibration's."""

    left_pan: float | None = None
    left_tilt: float | None = None
    right_pan: float | None = None
    right_tilt: float | None = None

    def __post_init__(self) -> None:
        for name in SERVO_NAMES:
            value = getattr(self, name)
            if value is None:
                continue
            if not math.isfinite(value) or abs(value) > MAX_TRIM_DEG:
                raise ValueError(
                    f"{name} = {value!r}: a trim must be a number within ±{MAX_TRIM_DEG:g}° "
                    f"(re-seat the servo horn if it is further off)"
                )

    def as_dict(self) -> dict[str, float]:
        """The trims that are set, {servo name: deg}."""
        return {n: v for n in SERVO_NAMES if (v := getattr(self, n)) is not None}

    @classmethod
    def of(cls, calib: EyesCalibration) -> EyesTrims:
        """The trims a calibration has now."""
        return cls(*(s.trim_deg for s in calib.servos()))


@dataclass(frozen=True, slots=True)
class TrimsFile:
    """The contents of a trims file."""

    trim_deg: EyesTrims = field(default_factory=EyesTrims)


def load_trims(path: Path) -> EyesTrims:
    """Read and check a trims file; `ConfigError` (one line, naming file and key) if invalid."""
    data = load_toml(path)
    if "trim_deg" not in data:
        raise ConfigError(
            f"trims file {path}: no [trim_deg] table (write one with `nod eyes calibrate`)"
        )
    try:
        return from_mapping(TrimsFile, data).trim_deg
    except ConfigError as exc:
        raise ConfigError(f"trims file {path}: {exc}") from None


def apply_trims(calib: EyesCalibration, trims: EyesTrims, source: str = "trims") -> EyesCalibration:
    """`calib` with the trims that are set.

    Refuses (`ConfigError`) a trim that puts a servo's centre (the neutral gaze) outside that
    servo's limits: neutral is the eyes' safe state and must never be clamped.
    """
    servos = {}
    for name, value in trims.as_dict().items():
        servo = getattr(calib, name)
        centre = 90.0 + value
        if not servo.min_deg <= centre <= servo.max_deg:
            raise ConfigError(
                f"{source}: {name} trim {value:+.2f}° puts its centre at {centre:.2f}°, outside "
                f"the servo's limits [{servo.min_deg:g}, {servo.max_deg:g}]°"
            )
        servos[name] = dataclasses.replace(servo, trim_deg=value)
    return dataclasses.replace(calib, **servos)


def load_and_apply(calib: EyesCalibration, path: Path | None) -> EyesCalibration:
    """`calib` with the trims file at `path` laid over it (unchanged when `path` is None)."""
    if path is None:
        return calib
    return apply_trims(calib, load_trims(path), f"trims file {path}")


def trims_toml(trims: EyesTrims, header: str = "") -> str:
    """A trims file: comment header, then `[trim_deg]` with every servo that is set."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    lines += ["[trim_deg]"] if not lines else ["", "[trim_deg]"]
    lines += [f"{name} = {value!r}" for name, value in trims.as_dict().items()]
    return "\n".join(lines) + "\n"
