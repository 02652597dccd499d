"""`nod actuation calibrate`: record the arm's five poses by moving it by hand.

Torque goes off (the operator supports the arm), then for each pose the operator moves the arm
and confirms; the present position of every servo is read and the poses are written, together
with the rest of the arm configuration, to a TOML file that `nod actuation --driver feetech`
loads. Prompting and output are injected (`prompt`, `say`), so the whole dialogue is testable.
Torque stays off at the end: the arm rests where the operator left it.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from services.actuation.arm_path import POSE_NAMES, ArmPoses
from services.actuation.feetech import FeetechBus
from services.actuation.feetech_arm import FeetechArmConfig
from services.core.cli import Parser
from services.core.config import ConfigError, from_mapping, load_toml
from services.core.serial_link import LinkError, SerialLink

Prompt = Callable[[str], str]
Say = Callable[[str], None]

POSE_HELP: dict[str, str] = {
    "home": "the rest pose, clear of both buzzers",
    "above_red": "hovering a few centimetres above the red buzzer",
    "press_red": "pressing the red buzzer down (until it clicks)",
    "above_blue": "hovering a few centimetres above the blue buzzer",
    "press_blue": "pressing the blue buzzer down (until it clicks)",
}


class CalibrationAbortedError(RuntimeError):
    """The operator answered "q"."""


def _ask(prompt: Prompt, message: str) -> None:
    if prompt(message).strip().lower() in ("q", "quit"):
        raise CalibrationAbortedError("calibration aborted by the operator; nothing written")


def record_poses(bus: FeetechBus, ids: tuple[int, ...], prompt: Prompt, say: Say) -> ArmPoses:
    """Torque off, then read the present positions once per pose, on the operator's word."""
    _ask(prompt, "Torque will be switched OFF: support the arm with one hand. Enter (q quits) ")
    bus.set_torque(ids, False)
    poses: dict[str, tuple[int, ...]] = {}
    for name in POSE_NAMES:
        _ask(prompt, f"Move the arm to {name.upper()}: {POSE_HELP[name]}. Enter (q quits) ")
        poses[name] = bus.read_positions(ids)
        say(f"  {name:<10} = {list(poses[name])}")
    return ArmPoses(**poses)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, tuple | list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} to TOML")


def config_toml(config: Any, header: str = "") -> str:
    """A flat-or-nested frozen dataclass as TOML (scalars first, then one table per field)."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    tables: list[tuple[str, Any]] = []
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            tables.append((f.name, value))
        else:
            lines.append(f"{f.name} = {_toml_value(value)}")
    for name, table in tables:
        lines.append("")
        lines.append(f"[{name}]")
        lines.extend(
            f"{f.name} = {_toml_value(getattr(table, f.name))}" for f in dataclasses.fields(table)
        )
    return "\n".join(lines) + "\n"


def calibrate(
    port: str,
    out: Path,
    base: FeetechArmConfig | None = None,
    *,
    prompt: Prompt = input,
    say: Say = print,
    link: SerialLink | None = None,
) -> FeetechArmConfig:
    """Record the poses of the arm on `port` and write the arm file `out`; return its config.

    `base` supplies everything but the poses (ids, baud rate, motion timing); defaults if None.
    """
    cfg = base if base is not None else FeetechArmConfig()
    link = link if link is not None else SerialLink(port, cfg.baudrate, cfg.link)
    link.open()
    try:
        bus = FeetechBus(link, cfg.series)
        for servo_id in cfg.ids:
            bus.ping(servo_id)
        say(f"Found servos {list(cfg.ids)} on {port}.")
        poses = record_poses(bus, cfg.ids, prompt, say)
    finally:
        link.close()
    result = dataclasses.replace(cfg, poses=poses)  # validates the poses against the ids
    header = (
        "Feetech arm calibration, written by `nod actuation calibrate`.\n"
        "Poses are servo steps in `ids` order; see docs/hardware.md."
    )
    out.write_text(config_toml(result, header))
    say(f"Wrote {out}. Torque is off: rest the arm before letting go.")
    return result


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod actuation calibrate`."""
    p = Parser(
        prog="nod actuation calibrate",
        description="Record the arm's poses (home, above/press red, above/press blue) by hand.",
    )
    p.add_argument("--port", required=True, help="serial port of the servo bus adapter")
    p.add_argument("--out", type=Path, required=True, help="arm file to write (TOML)")
    p.add_argument(
        "--base",
        type=Path,
        default=None,
        help="existing arm file whose ids, baud rate and timing are kept",
    )
    p.add_argument(
        "--ids",
        default=None,
        help="comma-separated servo ids, base of the arm to wrist (default 1,2,3,4,5,6)",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the calibration dialogue on the terminal."""
    args = build_parser().parse_args(argv)
    try:
        base = (
            FeetechArmConfig()
            if args.base is None
            else from_mapping(FeetechArmConfig, load_toml(args.base))
        )
        if args.ids is not None:
            ids = tuple(int(i) for i in args.ids.split(","))
            base = dataclasses.replace(base, ids=ids, poses=ArmPoses())
        calibrate(args.port, args.out, base)
    except (ConfigError, ValueError, LinkError, CalibrationAbortedError) as exc:
        print(f"nod actuation calibrate: {exc}", file=sys.stderr)
        return 2
    return 0
