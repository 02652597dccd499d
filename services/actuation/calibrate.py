"""`nod actuation calibrate`: record the arm's poses by moving it by hand.

The poses are home and, for each option by name, one above its buzzer and one pressing it
(`--names`, default the paper's red,blue: five poses; `--names red,blue,green` seven). Torque
goes off (the operator supports the arm), then for each pose the operator moves the arm
and confirms; the present position of every servo is read and the poses are written, together
with the rest of the arm configuration, to a TOML file that `nod actuation --driver feetech`
loads. Prompting and output are injected (`prompt`, `say`), so the whole dialogue is testable.
Torque stays off at the end: the arm rests where the operator left it.

A pose is refused as soon as it is recorded — one line, and nothing is written — when

- it is the same as an earlier pose: every joint within `DUPLICATE_STEPS` (Enter pressed twice
  without moving the arm leaves a path segment of zero length: a "press" that presses nothing);
- a joint lies outside its servo's angle limits (the `min/max_position_limit` registers in the
  servo's EEPROM, which clamp every goal; the full turn when they are unset): the servo could be
  pushed there by hand but can never be commanded there.

With `--verify`, once every pose is recorded, torque goes on and the arm visits each pose along
its path at `goal_speed`; a pose that a servo does not reach within `REACH_STEPS` before the
travel time plus `verify_timeout_s` is refused the same way (the arm then holds where it
stopped). A verified arm ends holding home, torque on.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from services.actuation.arm_path import ArmPoses, Pose, pose_distance, pose_names
from services.actuation.feetech import RESOLUTION, FeetechBus, Series
from services.actuation.feetech_arm import FeetechArmConfig
from services.core.cli import Parser, fail
from services.core.config import ConfigError, from_mapping, load_toml
from services.core.serial_link import LinkError, SerialLink
from services.model.geometry import COLOURS

Prompt = Callable[[str], str]
Say = Callable[[str], None]



def pose_help(pose: str) -> str:
    """What the operator does for a pose (`home`, `above_<option>`, `press_<option>`)."""
    if pose == "home":
        return "the rest pose, clear of every buzzer"
    kind, _, name = pose.partition("_")
    if kind == "above":
        return f"hovering a few centimetres above the {name} buzzer"
    return f"pressing the {name} buzzer down (until it clicks)"


# Two poses whose every joint is within this many steps are one pose recorded twice. A limp arm
# held still reads within ±1–2 steps (encoder noise, the hand's tremor), while the smallest pose
# difference that means anything — above → press, a descent of >= 5 mm at the end of a 10–12 cm
# link — is ~2.5° ≈ 28 STS steps. 10 steps (0.9°) is 5× the noise and a third of that; SCS
# servos (1024 steps per turn) get the same angle, 3 steps.
DUPLICATE_STEPS: dict[Series, int] = {"sts": 10, "scs": 3}
# A verified pose is reached when every joint is within this many steps of its goal. An STS3215
# under gravity settles a few to ~20 steps short of a goal (proportional control; more on the
# shoulder lift), and a press pose pushes into the buzzer's spring; 40 steps (3.5°) accepts that
# and still catches a servo that is blocked, overloaded or clamped by its angle limits.
REACH_STEPS: dict[Series, int] = {"sts": 40, "scs": 10}


def verify_route(names: tuple[str, ...]) -> tuple[str, ...]:
    """The path `--verify` drives from the last recorded pose (the last option's press).

    Every pose visited, sideways only when up and through home, as the service moves the arm.
    """
    route: tuple[str, ...] = (f"above_{names[-1]}", "home")
    for name in names:
        route += (f"above_{name}", f"press_{name}", f"above_{name}", "home")
    return route


VERIFY_ROUTE = verify_route(COLOURS)  # the paper's: above_blue, home, above_red, …, home
UNLIMITED_SPEED = 3000  # steps/s assumed for travel time when goal_speed is 0 (STS3215 ~ 3400)


class CalibrationAbortedError(RuntimeError):
    """The operator answered "q"."""


class PoseRejectedError(ValueError):
    """A recorded pose is a duplicate or unreachable; the message says which and why."""


def read_limits(
    bus: FeetechBus, ids: tuple[int, ...], series: Series
) -> dict[int, tuple[int, int]]:
    """Each servo's angle limits (steps) from its EEPROM; the full turn where they are unset."""
    top = RESOLUTION[series] - 1
    limits = {}
    for i in ids:
        lo = bus.read_register(i, "min_position_limit")
        hi = bus.read_register(i, "max_position_limit")
        limits[i] = (max(lo, 0), min(hi, top)) if lo < hi else (0, top)  # 0/0: no limits set
    return limits


def check_pose(
    name: str,
    pose: Pose,
    recorded: dict[str, Pose],
    ids: tuple[int, ...],
    limits: dict[int, tuple[int, int]],
    tolerance: int,
) -> None:
    """Raise `PoseRejectedError` if `pose` is unreachable or repeats a recorded pose.

    `limits` maps servo id → (lowest, highest) steps; a servo without an entry is not checked.
    """
    for servo_id, value in zip(ids, pose, strict=True):
        lo, hi = limits.get(servo_id, (value, value))
        if not lo <= value <= hi:
            raise PoseRejectedError(
                f"pose {name} is unreachable: servo {servo_id} is at {value}, outside its angle "
                f"limits [{lo}, {hi}] (min/max_position_limit in the servo's EEPROM); "
                f"nothing written"
            )
    for other, known in recorded.items():
        if pose_distance(pose, known) <= tolerance:
            raise PoseRejectedError(
                f"pose {name} is the same as {other}: every joint within {tolerance} steps "
                f"(largest difference {pose_distance(pose, known)}); move the arm to {name} and "
                f"calibrate again; nothing written"
            )


def check_names(names: tuple[str, ...]) -> None:
    """Refuse (ValueError, one line) option names that cannot name poses."""
    if len(names) < 2 or len(set(names)) != len(names) or not all(names):
        raise ValueError(f"--names needs two or more distinct option names, got {list(names)}")
    if any(not name.replace("-", "").replace("_", "").isalnum() for name in names):
        raise ValueError(f"--names: option names are letters and digits, got {list(names)}")


def _ask(prompt: Prompt, message: str) -> None:
    if prompt(message).strip().lower() in ("q", "quit"):
        raise CalibrationAbortedError("calibration aborted by the operator; nothing written")


def record_poses(
    bus: FeetechBus,
    ids: tuple[int, ...],
    prompt: Prompt,
    say: Say,
    limits: dict[int, tuple[int, int]] | None = None,
    tolerance: int = 0,
    names: tuple[str, ...] = COLOURS,
) -> ArmPoses:
    """Torque off, then read the present positions once per pose, on the operator's word.

    The poses of options `names` (`pose_names`). Each pose is checked as it is read
    (`check_pose`) against `limits` (default: no limits) and the poses before it (`tolerance`
    steps).
    """
    limits = limits if limits is not None else {}
    _ask(prompt, "Torque will be switched OFF: support the arm with one hand. Enter (q quits) ")
    bus.set_torque(ids, False)
    poses: dict[str, tuple[int, ...]] = {}
    for name in pose_names(names):
        _ask(prompt, f"Move the arm to {name.upper()}: {pose_help(name)}. Enter (q quits) ")
        pose = bus.read_positions(ids)
        say(f"  {name:<10} = {list(pose)}")
        check_pose(name, pose, poses, ids, limits, tolerance)
        poses[name] = pose
    return ArmPoses(**poses)


def verify_poses(
    bus: FeetechBus,
    cfg: FeetechArmConfig,
    poses: ArmPoses,
    say: Say,
    timeout_s: float,
    *,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> None:
    """Torque on and drive `verify_route`; `PoseRejectedError` for a pose a servo cannot reach.

    Goals are first set to the present positions (no jump when torque comes on). On a refusal
    the arm holds where it stopped.
    """
    ids, speed = cfg.ids, cfg.goal_speed if cfg.goal_speed > 0 else UNLIMITED_SPEED
    reach = REACH_STEPS[cfg.series]
    present = bus.read_positions(ids)
    bus.write_goals(dict(zip(ids, present, strict=True)), cfg.goal_speed)
    bus.set_torque(ids, True)
    table = poses.table()
    for name in verify_route(poses.names):
        goal = table[name]
        bus.write_goals(dict(zip(ids, goal, strict=True)), cfg.goal_speed)
        allowed = pose_distance(goal, present) / speed + timeout_s
        deadline = clock() + allowed
        while True:
            sleep(min(0.02, allowed))
            present = bus.read_positions(ids)
            if pose_distance(goal, present) <= reach:
                break
            if clock() >= deadline:
                bus.write_goals(dict(zip(ids, present, strict=True)), cfg.goal_speed)  # hold
                worst = max(
                    zip(ids, present, goal, strict=True), key=lambda t: abs(t[1] - t[2])
                )
                raise PoseRejectedError(
                    f"pose {name} is unreachable: servo {worst[0]} stopped at {worst[1]}, "
                    f"commanded {worst[2]} (off by {abs(worst[1] - worst[2])} > {reach} steps "
                    f"after {allowed:.1f} s); the arm holds there, torque on; nothing written"
                )
        say(f"  reached {name:<10} {list(present)}")


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
    tables: list[tuple[str, dict[str, Any]]] = []
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if hasattr(value, "table"):  # a table whose keys are data (`ArmPoses`: by option name)
            tables.append((f.name, value.table()))
        elif dataclasses.is_dataclass(value):
            fields = dataclasses.fields(value)
            tables.append((f.name, {g.name: getattr(value, g.name) for g in fields}))
        else:
            lines.append(f"{f.name} = {_toml_value(value)}")
    for name, table in tables:
        lines.append("")
        lines.append(f"[{name}]")
        lines.extend(f"{key} = {_toml_value(value)}" for key, value in table.items())
    return "\n".join(lines) + "\n"


def calibrate(
    port: str,
    out: Path,
    base: FeetechArmConfig | None = None,
    *,
    prompt: Prompt = input,
    say: Say = print,
    link: SerialLink | None = None,
    verify: bool = False,
    verify_timeout_s: float = 2.0,
    names: tuple[str, ...] | None = None,
) -> FeetechArmConfig:
    """Record the poses of the arm on `port` and write the arm file `out`; return its config.

    `base` supplies everything but the poses (ids, baud rate, motion timing); defaults if None.
    `names`: the options whose poses are recorded (default: the base's, else red and blue).
    A duplicate or unreachable pose raises `PoseRejectedError` and nothing is written; `verify`
    also drives every pose on the bus (torque on) before writing.
    """
    cfg = base if base is not None else FeetechArmConfig()
    if names is None:
        names = cfg.poses.names if cfg.poses.calibrated else COLOURS
    check_names(names)
    link = link if link is not None else SerialLink(port, cfg.baudrate, cfg.link)
    link.open()
    try:
        bus = FeetechBus(link, cfg.series)
        for servo_id in cfg.ids:
            bus.ping(servo_id)
        limits = read_limits(bus, cfg.ids, cfg.series)
        say(f"Found servos {list(cfg.ids)} on {port}; angle limits {limits}.")
        poses = record_poses(
            bus, cfg.ids, prompt, say, limits, DUPLICATE_STEPS[cfg.series], names
        )
        result = dataclasses.replace(cfg, poses=poses)  # validates the poses against the ids
        if verify:
            _ask(
                prompt,
                "Torque goes ON and the arm visits every pose at goal_speed: clear the table, "
                "keep a hand on the e-stop. Enter (q quits) ",
            )
            verify_poses(bus, cfg, poses, say, verify_timeout_s)
    finally:
        link.close()
    header = (
        "Feetech arm calibration, written by `nod actuation calibrate`.\n"
        "Poses are servo steps in `ids` order; see docs/hardware.md."
    )
    out.write_text(config_toml(result, header))
    if verify:
        say(f"Wrote {out}. Every pose verified; the arm holds home, torque on.")
    else:
        say(f"Wrote {out}. Torque is off: rest the arm before letting go.")
    return result


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod actuation calibrate`."""
    p = Parser(
        prog="nod actuation calibrate",
        description="Record the arm's poses by hand: home, and above and pressing each "
        "option's buzzer (default red, blue).",
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
    p.add_argument(
        "--names",
        default=None,
        help="comma-separated option names, one press pose each, e.g. red,blue,green "
        "(default: the --base file's, else red,blue)",
    )
    p.add_argument(
        "--verify",
        action="store_true",
        help="after recording, torque on and drive every pose; refuse one a servo cannot reach",
    )
    p.add_argument(
        "--verify-timeout",
        type=float,
        default=2.0,
        metavar="S",
        help="time allowed beyond the travel time at goal_speed to reach a pose (default 2 s)",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the calibration dialogue on the terminal."""
    p = build_parser()
    args = p.parse_args(argv)
    if not (math.isfinite(args.verify_timeout) and args.verify_timeout > 0):
        p.error(f"--verify-timeout must be > 0 s, got {args.verify_timeout}")
    try:
        base = (
            FeetechArmConfig()
            if args.base is None
            else from_mapping(FeetechArmConfig, load_toml(args.base))
        )
        if args.ids is not None:
            ids = tuple(int(i) for i in args.ids.split(","))
            base = dataclasses.replace(base, ids=ids, poses=ArmPoses())
        names = None if args.names is None else tuple(n.strip() for n in args.names.split(","))
        calibrate(
            args.port, args.out, base, verify=args.verify, verify_timeout_s=args.verify_timeout,
            names=names,
        )
    except EOFError:
        return fail("nod actuation calibrate", "the input ended; nothing written")
    except (ConfigError, ValueError, LinkError, CalibrationAbortedError) as exc:
        return fail("nod actuation calibrate", exc)
    return 0
