"""Choosing an arm driver from the command line: `--driver`, `--port` and an arm file.

"sim" is the kinematic `SimArm`; "feetech" is a Feetech STS/SCS servo arm (SO-100/SO-101)
whose poses come from the arm file written by `nod actuation calibrate` (see
deploy/hardware/arm.example.toml and docs/hardware.md).
"""

from __future__ import annotations

from pathlib import Path

from services.actuation.feetech_arm import FeetechArm, FeetechArmConfig
from services.actuation.threaded_arm import ThreadedArm
from services.core.config import from_mapping, load_toml
from services.model.arm import ArmDriver, SimArm
from services.model.arm_kinematics import SimArmParams
from services.model.geometry import TableLayout

ARM_DRIVERS: tuple[str, ...] = ("sim", "feetech")


def load_arm_config(path: Path) -> FeetechArmConfig:
    """Read an arm file; unknown keys and uncalibrated poses are errors naming the fix."""
    return from_mapping(FeetechArmConfig, load_toml(path))


def make_arm_driver(
    kind: str,
    port: str | None,
    config_path: Path | None,
    layout: TableLayout,
    sim_params: SimArmParams | None = None,
    *,
    t0: float = 0.0,
) -> ArmDriver:
    """An unconnected arm driver of `kind` ("sim" or "feetech").

    `layout` and `sim_params.home` also place the Feetech arm's end-effector estimate on the
    table; `t0` is the sim arm's start time (s) — pass the service clock's now.
    """
    if kind not in ARM_DRIVERS:
        raise ValueError(f"unknown arm driver {kind!r}; expected one of {ARM_DRIVERS}")
    params = sim_params if sim_params is not None else SimArmParams()
    if kind == "sim":
        return SimArm(layout, params, t0=t0)
    if not port:
        raise ValueError("the feetech arm driver needs --port (the bus adapter, e.g. /dev/ttyACM0)")
    if config_path is None:
        raise ValueError(
            "the feetech arm driver needs an arm file with its poses: record one with "
            "`nod actuation calibrate --port DEV --out arm.toml` "
            "(example: deploy/hardware/arm.example.toml)"
        )
    # The bus I/O runs on its own thread: the actuation tick never waits for the servos.
    return ThreadedArm(FeetechArm(port, load_arm_config(config_path), layout, home=params.home))
