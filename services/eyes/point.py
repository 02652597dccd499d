r"""`nod eyes point`: look at one gaze on the bench, without Zenoh, and say what was sent.

    nod eyes point --yaw 0.53 --pitch -0.53 --driver maestro --port /dev/ttyACM0 \
        --eyes-config eyes.toml [--trims eyes_trims.toml] [--hold 5]

The gaze (radians; positive yaw looks toward red) becomes servo targets through the model the
eyes service uses (`services.model.servos`), clamped to the calibrated limits; every clamped
servo is reported on stderr with the angle it asked for — nothing out of range is sent. After
sending, the tool waits until the controller confirms the targets (see `services.eyes.bench`)
and prints them. Without `--hold` the eyes stay there (the controller keeps its last targets);
with `--hold S` they go back to neutral after S seconds. Ctrl-C (or SIGTERM) at any point also
returns them to neutral.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import time

from services.core.cli import Parser, fail, finite_float
from services.eyes.bench import (
    BenchError,
    add_bench_args,
    describe,
    open_driver,
    settle,
    sigterm_as_interrupt,
    targets_table,
)
from services.eyes.servos import ServoDriver
from services.model.gaze import GazeCommand
from services.model.servos import SERVO_NAMES, requested_angles, servo_targets

PROG = "nod eyes point"


def _seconds(text: str) -> float:
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod eyes point`."""
    p = Parser(
        prog=PROG,
        description="Point both eyes at one gaze (radians) through the eyes driver, on the bench.",
    )
    p.add_argument(
        "--yaw", type=finite_float, required=True, help="rad; positive looks toward red (e.g. 0.53)"
    )
    p.add_argument("--pitch", type=finite_float, default=0.0, help="rad (default 0)")
    add_bench_args(p)
    p.add_argument(
        "--hold",
        type=_seconds,
        default=None,
        metavar="S",
        help="keep the pose S seconds, then go back to neutral (default: stay)",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log the driver at debug level")
    return p


def clamp_report(gaze: GazeCommand, driver: ServoDriver, clamped: tuple[str, ...]) -> list[str]:
    """One line per clamped servo: the angle asked for and the limit sent instead."""
    asked = dict(zip(SERVO_NAMES, requested_angles(gaze, driver.calibration), strict=True))
    lines = []
    for name in clamped:
        c = getattr(driver.calibration, name)
        limit, which = (c.max_deg, "max_deg") if asked[name] > c.max_deg else (c.min_deg, "min_deg")
        lines.append(
            f"{PROG}: clamped {name}: the gaze asks {asked[name]:.2f}°, sent {limit:g}° ({which})"
        )
    return lines


def point(driver: ServoDriver, gaze: GazeCommand, hold_s: float | None) -> int:
    """Send the gaze, report, settle, print; hold and return to neutral if asked."""
    device = describe(driver)
    targets = servo_targets(gaze, driver.calibration)
    neutral_targets = servo_targets(GazeCommand(), driver.calibration)
    applied = driver.send(targets)
    for line in clamp_report(gaze, driver, applied.clamped):
        print(line, file=sys.stderr)
    waited = settle(driver, applied, None)
    print(f"gaze yaw={gaze.yaw:+.3f} pitch={gaze.pitch:+.3f} rad → {device}")
    print(targets_table(applied))
    print(f"settled in {waited:.2f} s")
    if hold_s is None:
        return 0
    time.sleep(hold_s)
    back = driver.neutral()
    settle(driver, back, applied)
    print(f"held {hold_s:g} s; back to neutral {_pulses(neutral_targets.pulses_us)}")
    return 0


def _pulses(pulses: tuple[float, ...]) -> str:
    return "(" + ", ".join(f"{p:.1f}" for p in pulses) + " µs)"


def main(argv: list[str] | None = None) -> int:
    """Point the eyes; 2 on bad input or an unusable port, 1 if the controller misbehaves."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        gaze = GazeCommand(args.yaw, args.pitch)
        driver = open_driver(args)
    except (ValueError, BenchError) as exc:
        return fail(PROG, exc)
    with sigterm_as_interrupt():
        try:
            return point(driver, gaze, args.hold)
        except KeyboardInterrupt:
            back = driver.neutral()
            with contextlib.suppress(BenchError):
                settle(driver, back, None, timeout_s=1.0)
            print(f"{PROG}: interrupted; eyes back to neutral", file=sys.stderr)
            return 130
        except BenchError as exc:
            print(f"{PROG}: {exc}", file=sys.stderr)
            return 1
        finally:
            driver.disconnect()
