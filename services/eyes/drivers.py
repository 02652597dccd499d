"""Choosing an eyes driver from the command line: `--driver`, `--port` and an eyes file.

The eyes file (see deploy/hardware/eyes.example.toml) holds the servo calibration and the
settings of both controllers; only the section of the chosen driver is used:

    [calibration.left_pan]   trim_deg, direction, min_deg, max_deg, min_pulse_us, max_pulse_us
    [maestro]                channels, baudrate, speed, acceleration, [maestro.link]
    [arduino]                baudrate, boot_wait_s, [arduino.link]

A trims file (`--trims`, written by `nod eyes calibrate`; see `services.eyes.trims`) is laid over
whichever calibration is in effect and replaces only the servos' `trim_deg`.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path

from services.core.config import from_mapping, load_toml
from services.eyes.arduino import ArduinoEyesConfig, ArduinoServoDriver
from services.eyes.maestro import MaestroConfig, MaestroServoDriver
from services.eyes.servos import ServoDriver, SimServoDriver
from services.eyes.trims import load_and_apply
from services.model.servos import EyesCalibration

EYES_DRIVERS: tuple[str, ...] = ("sim", "maestro", "arduino")


def add_driver_args(p: argparse.ArgumentParser) -> None:
    """The flags that choose and calibrate the eyes driver (the service and its bench tools)."""
    p.add_argument(
        "--driver", choices=EYES_DRIVERS, default="sim", help="servo driver (default sim)"
    )
    p.add_argument("--port", default=None, help="serial port of the servo controller")
    p.add_argument(
        "--eyes-config", type=Path, default=None, help="eyes hardware file (channels, calibration)"
    )
    p.add_argument(
        "--trims",
        "--calibration",
        dest="trims",
        type=Path,
        default=None,
        metavar="FILE",
        help="trims file written by `nod eyes calibrate`, laid over the calibration",
    )


@dataclass(frozen=True, slots=True)
class EyesHardwareConfig:
    """The contents of an eyes file."""

    # Servo trims, directions and limits; None: use the rig config's [eyes] calibration.
    calibration: EyesCalibration | None = None
    maestro: MaestroConfig = field(default_factory=MaestroConfig)  # Pololu Maestro wiring
    arduino: ArduinoEyesConfig = field(default_factory=ArduinoEyesConfig)  # eyes.ino link


def load_eyes_config(path: Path | None) -> EyesHardwareConfig:
    """Read an eyes file (defaults when None); unknown keys are errors naming the key."""
    if path is None:
        return EyesHardwareConfig()
    return from_mapping(EyesHardwareConfig, load_toml(path))


def make_eyes_driver(
    kind: str,
    port: str | None,
    config_path: Path | None,
    *,
    calibration: EyesCalibration | None = None,
    trims: Path | None = None,
) -> ServoDriver:
    """An unconnected eyes driver of `kind` ("sim", "maestro" or "arduino").

    The calibration is the eyes file's `[calibration]` if it has one, else `calibration` (the
    rig config's `[eyes]`), else the defaults; the trims file `trims`, if given, then replaces
    the servos' trims. Real drivers need `port`.
    """
    if kind not in EYES_DRIVERS:
        raise ValueError(f"unknown eyes driver {kind!r}; expected one of {EYES_DRIVERS}")
    hw = load_eyes_config(config_path)
    calib = hw.calibration if hw.calibration is not None else calibration
    if trims is not None:
        calib = load_and_apply(calib if calib is not None else EyesCalibration(), trims)
    if kind == "sim":
        return SimServoDriver(calib)
    if not port:
        raise ValueError(
            f"the {kind} eyes driver needs --port (e.g. /dev/ttyACM0 for a Maestro's command "
            f"port, /dev/ttyUSB0 or /dev/ttyACM0 for an Arduino)"
        )
    if kind == "maestro":
        return MaestroServoDriver(port, hw.maestro, calib)
    return ArduinoServoDriver(port, hw.arduino, calib)
