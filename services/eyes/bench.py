"""What the eyes' bench tools (`nod eyes point`, `nod eyes calibrate`) share.

They open the eyes driver directly — no Zenoh, on the eyes' host — with the same flags, the same
calibration (eyes file, `--params`, trims file) and the same gaze → servo model as the service.
A port that another program holds (the eyes service, normally) is refused in one line: every
serial port is opened exclusively (`services.core.serial_link`).

"Settled" means the controller confirms it outputs the targets (the Maestro's Get Position, the
sketch's GET_PULSES; with a Maestro speed limit this waits for the ramp) and the servos have had
time to turn there (`SERVO_SPEED_DEG_S`). Hobby servos report nothing back, so that is the most
a host can know.

The readbacks run on the caller's thread while the driver's I/O thread is idle: `settle` waits
for the I/O thread to finish its work first, and nothing wakes it again until the next `send`.
"""

from __future__ import annotations

import argparse
import signal
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

from services.core.cli import add_params_arg
from services.core.config import load_params
from services.core.serial_link import LinkError
from services.eyes.arduino import ArduinoServoDriver
from services.eyes.drivers import add_driver_args, make_eyes_driver
from services.eyes.maestro import MaestroServoDriver, quarter_us
from services.eyes.serial_servo import SerialServoDriver
from services.eyes.servos import ServoDriver
from services.model.servos import SERVO_NAMES, ServoTargets

# SG90-class micro servos turn 60° in ~0.1 s unloaded (600°/s); half that leaves margin for the
# eyeball's inertia and a sagging supply. Only used to wait, never to command.
SERVO_SPEED_DEG_S = 300.0
# How long the controller may take to confirm targets (a Maestro speed ramp included).
CONFIRM_TIMEOUT_S = 3.0


class BenchError(RuntimeError):
    """A bench tool cannot go on; the message is one line for the operator."""


def add_bench_args(p: argparse.ArgumentParser) -> None:
    """A bench tool's flags: the eyes driver as `nod eyes` takes it, and `--params`."""
    add_driver_args(p)
    add_params_arg(p)


def open_driver(args: argparse.Namespace) -> ServoDriver:
    """The connected eyes driver the flags describe; `BenchError` if the port is unusable.

    Invalid configuration raises `ValueError` (one line, naming the file and key).
    """
    cfg = load_params(args.params)
    driver = make_eyes_driver(
        args.driver, args.port, args.eyes_config, calibration=cfg.eyes, trims=args.trims
    )
    try:
        driver.connect()
    except (LinkError, ConnectionError, OSError) as exc:
        text = " ".join(str(exc).split())
        if "exclusively lock" in text:
            raise BenchError(
                f"{args.port} is held by another program — is `nod eyes` running on this host? "
                f"Stop it first: a bench tool must not fight the service for the servos"
            ) from None
        raise BenchError(text) from None
    return driver


def describe(driver: ServoDriver) -> str:
    """E.g. "the Maestro on /dev/ttyACM0"; the sim driver says nothing moves."""
    if isinstance(driver, SerialServoDriver):
        return f"the {driver.device} on {driver.link.port}"
    return "the simulated eyes (sim driver: nothing moves)"


def controller_output_us(driver: ServoDriver) -> tuple[float, ...] | None:
    """The pulses (µs) the controller outputs now, or None if it cannot say (sim)."""
    if isinstance(driver, MaestroServoDriver):
        return driver.read_positions_us()
    if isinstance(driver, ArduinoServoDriver):
        return tuple(float(p) for p in driver.read_pulses_us())
    return None


def wire_us(driver: ServoDriver, targets: ServoTargets) -> tuple[float, ...]:
    """The pulses (µs) the protocol carries for `targets` (Maestro: ¼ µs; Arduino: whole µs)."""
    if isinstance(driver, MaestroServoDriver):
        return tuple(quarter_us(p) / 4.0 for p in targets.pulses_us)
    return tuple(float(round(p)) for p in targets.pulses_us)


def settle(
    driver: ServoDriver,
    applied: ServoTargets,
    previous: ServoTargets | None,
    timeout_s: float = CONFIRM_TIMEOUT_S,
) -> float:
    """Wait until the controller outputs `applied` and the servos had time to get there.

    `previous` (the targets before, None if unknown: assume the far end of the travel) sets the
    travel time. Returns the seconds waited; raises `BenchError` when the controller does not
    confirm within `timeout_s`.
    """
    start = time.monotonic()
    deadline = start + timeout_s
    if isinstance(driver, SerialServoDriver):
        if not driver.flush(timeout_s) or not driver.settle(max(0.0, deadline - time.monotonic())):
            raise BenchError(
                f"the {driver.device} did not take the targets within {timeout_s:g} s"
                + (f": {driver.fault}" if driver.fault else "")
            )
        if driver.fault:
            raise BenchError(driver.fault)
        want = wire_us(driver, applied)
        while True:
            try:
                got = controller_output_us(driver)
            except (LinkError, ValueError) as exc:
                raise BenchError(f"the {driver.device} did not report its outputs: {exc}") from None
            if got is None or all(abs(g - w) < 0.5 for g, w in zip(got, want, strict=True)):
                break
            if time.monotonic() >= deadline:
                pairs = ", ".join(
                    f"{n} {g:g}≠{w:g}"
                    for n, g, w in zip(SERVO_NAMES, got, want, strict=True)
                    if abs(g - w) >= 0.5
                )
                raise BenchError(
                    f"the {driver.device} outputs other pulses than sent (µs: {pairs}); check "
                    f"its channel range / the sketch's MIN/MAX_PULSE_US"
                )
            time.sleep(0.01)
    if not isinstance(driver, SerialServoDriver):
        return time.monotonic() - start  # nothing moves
    if previous is None:
        travel_deg = 180.0
    else:
        travel_deg = max(
            abs(a - b) for a, b in zip(applied.angles_deg, previous.angles_deg, strict=True)
        )
    rest = start + travel_deg / SERVO_SPEED_DEG_S - time.monotonic()
    if rest > 0:
        time.sleep(rest)
    return time.monotonic() - start


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt too, so `kill` and Ctrl-C both end in neutral.

    SIGINT is set explicitly as well: a process started with SIGINT ignored (a job started
    with `&` by a script, a test runner's worker) would otherwise ignore Ctrl-C and `kill -INT`.
    """

    def handler(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt

    try:
        old = signal.signal(signal.SIGTERM, handler)
        old_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    except ValueError:  # not the main thread (a test calling main): leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)
        signal.signal(signal.SIGINT, old_int)


def targets_table(targets: ServoTargets) -> str:
    """The targets as a small table: servo, angle (deg), pulse (µs), clamped."""
    lines = [f"{'servo':<11} {'angle_deg':>9} {'pulse_us':>9}"]
    for name, angle, pulse in zip(
        SERVO_NAMES, targets.angles_deg, targets.pulses_us, strict=True
    ):
        mark = "  clamped" if name in targets.clamped else ""
        lines.append(f"{name:<11} {angle:>9.2f} {pulse:>9.1f}{mark}")
    return "\n".join(lines)
