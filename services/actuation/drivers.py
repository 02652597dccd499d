"""Choosing an arm driver from the command line: `--driver`, `--port` and an arm file.

"sim" is the kinematic `SimArm` (`OptionsSimArm` over N boxes); "feetech" is a Feetech STS/SCS
servo arm (SO-100/SO-101) whose poses come from the arm file written by `nod actuation
calibrate` (see deploy/hardware/arm.example.toml and docs/hardware.md): one press pose per
option by name, so the same file drives the paper's red and blue and a table of N boxes.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from services.actuation.feetech_arm import FeetechArm, FeetechArmConfig
from services.actuation.threaded_arm import ThreadedArm
from services.core.config import from_mapping, load_toml
from services.model.arm import ArmState, OptionsArmState, OptionsSimArm, SimArm
from services.model.arm_kinematics import SimArmParams
from services.model.behaviour import ArmCommand, OptionsCommand
from services.model.geometry import Colour, OptionsLayout, TableLayout

ARM_DRIVERS: tuple[str, ...] = ("sim", "feetech")
PaperArm = SimArm | ThreadedArm[ArmCommand, Colour, ArmState]
OptionsArm = OptionsSimArm | ThreadedArm[OptionsCommand, int, OptionsArmState]


def load_arm_config(path: Path) -> FeetechArmConfig:
    """Read an arm file; unknown keys and uncalibrated poses are errors naming the fix."""
    return from_mapping(FeetechArmConfig, load_toml(path))


def feetech_config(port: str | None, config_path: Path | None) -> tuple[str, FeetechArmConfig]:
    """The Feetech arm's port and arm file, each refused in one line naming the fix when absent."""
    if not port:
        raise ValueError("the feetech arm driver needs --port (the bus adapter, e.g. /dev/ttyACM0)")
    if config_path is None:
        raise ValueError(
            "the feetech arm driver needs an arm file with its poses: record one with "
            "`nod actuation calibrate --port DEV --out arm.toml` "
            "(example: deploy/hardware/arm.example.toml)"
        )
    return port, load_arm_config(config_path)


def check_arm_file(config_path: Path, names: Sequence[str]) -> None:
    """Refuse (ValueError, one line) an arm file without a press pose for every option."""
    try:
        load_arm_config(config_path).poses.select(names)
    except ValueError as exc:
        raise ValueError(f"{config_path}: {exc}") from None


def _check_kind(kind: str) -> None:
    if kind not in ARM_DRIVERS:
        raise ValueError(f"unknown arm driver {kind!r}; expected one of {ARM_DRIVERS}")


def make_arm_driver(
    kind: str,
    port: str | None,
    config_path: Path | None,
    layout: TableLayout,
    sim_params: SimArmParams | None = None,
    *,
    t0: float = 0.0,
) -> PaperArm:
    """An unconnected arm driver of `kind` ("sim" or "feetech") for the paper's red and blue.

    `layout` and `sim_params.home` also place the Feetech arm's end-effector estimate on the
    table; `t0` is the sim arm's start time (s) — pass the service clock's now.
    """
    _check_kind(kind)
    params = sim_params if sim_params is not None else SimArmParams()
    if kind == "sim":
        return SimArm(layout, params, t0=t0)
    port, config = feetech_config(port, config_path)
    # The bus I/O runs on its own thread: the actuation tick never waits for the servos.
    return ThreadedArm(FeetechArm(port, config, layout, home=params.home))


def make_options_arm(
    kind: str,
    port: str | None,
    config_path: Path | None,
    layout: OptionsLayout,
    names: Sequence[str],
    sim_params: SimArmParams | None = None,
    *,
    t0: float = 0.0,
) -> OptionsArm:
    """An unconnected arm over the boxes of `layout`, box j option `names[j]`.

    The Feetech arm presses box j at the arm file's `press_<names[j]>` pose; a file without a
    pose for every option is refused in one line naming the missing ones.
    """
    _check_kind(kind)
    params = sim_params if sim_params is not None else SimArmParams()
    if kind == "sim":
        return OptionsSimArm(layout, params, t0=t0)
    port, config = feetech_config(port, config_path)
    try:
        arm = FeetechArm(port, config, layout, home=params.home, names=names)
    except ValueError as exc:
        raise ValueError(f"{config_path}: {exc}") from None
    return ThreadedArm(arm)
