r"""`nod eyes calibrate`: centre each eye servo by eye, then write the trims file the service loads.

    nod eyes calibrate --driver maestro --port /dev/ttyACM0 --eyes-config eyes.toml \
        --out eyes_trims.toml                                   # interactive, on the terminal
    nod eyes calibrate ... --out eyes_trims.toml --set left_pan=+1.5,right_tilt=-0.75
    printf 'dd2ws\n' | nod eyes calibrate ... --out eyes_trims.toml   # keys from stdin

The eyes are sent the neutral gaze (0, 0) with the trims being tuned, live, so the operator
nudges each servo until both eyes look straight ahead:

    1 / 2 (or Tab)   select the left / right eye
    a / d            pan trim − / + one step (← / → too)      A / D: five steps
    s / w            tilt trim − / + one step (↓ / ↑ too)     S / W: five steps
    0                the selected eye back to its starting trims
    Enter            accept: write the trims file
    q (or Esc)       quit without writing (the eyes go back to their starting trims)

"+" is a larger servo angle; whether that looks toward red or up depends on the servo's
`direction`. Trims start from the calibration in effect (eyes file, `--params`, or a previous
trims file given with `--trims`). `--set NAME=DEG,…` sets trims (absolute, degrees; a `rad`
suffix takes radians) without any keys; on a pipe, stdin is read as keys. Nothing is written
unless the controller confirmed the final targets. A trim is refused when it exceeds
±MAX_TRIM_DEG or puts a servo's centre outside its limits; the file is checked again on load.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import select
import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from services.core.cli import Parser, fail
from services.core.config import ConfigError
from services.eyes import bench
from services.eyes.servos import ServoDriver
from services.eyes.trims import MAX_TRIM_DEG, EyesTrims, apply_trims, load_and_apply, trims_toml
from services.model.servos import SERVO_NAMES, EyesCalibration

PROG = "nod eyes calibrate"
COARSE = 5  # an upper-case key moves this many steps
# Arrow keys (ANSI escape sequences) → the letter keys.
ARROWS = {"[A": "w", "[B": "s", "[C": "d", "[D": "a", "OA": "w", "OB": "s", "OC": "d", "OD": "a"}
HELP = (
    "1/2 or Tab: left/right eye · a/d (←/→): pan −/+ · s/w (↓/↑): tilt −/+ · upper case ×5 · "
    "0: reset eye · Enter: accept and write · q: quit without writing"
)


class CalibrationAbortedError(RuntimeError):
    """The operator quit, or the input ended before Enter: nothing is written."""


@dataclass
class TrimSession:
    """The trims being tuned and the key handling; pure (no I/O)."""

    base: EyesCalibration
    step_deg: float = 0.5
    eye: str = "left"
    message: str = ""
    start: dict[str, float] = field(init=False)
    trims: dict[str, float] = field(init=False)

    def __post_init__(self) -> None:
        self.start = EyesTrims.of(self.base).as_dict()
        self.trims = dict(self.start)

    @property
    def calibration(self) -> EyesCalibration:
        """The base calibration with the current trims."""
        return apply_trims(self.base, EyesTrims(**self.trims))

    def set(self, name: str, value_deg: float) -> None:
        """Set one trim; `ValueError` (one line) if out of range or past the servo's limits."""
        if name not in SERVO_NAMES:
            raise ValueError(f"unknown servo {name!r}; expected one of {', '.join(SERVO_NAMES)}")
        value = round(value_deg, 3)
        trial = dict(self.trims, **{name: value})
        apply_trims(self.base, EyesTrims(**trial), "--set")  # raises with the reason
        self.trims = trial

    def nudge(self, name: str, steps: int) -> None:
        """Move one trim by `steps` steps; at a limit, say so and leave it."""
        try:
            self.set(name, self.trims[name] + steps * self.step_deg)
            self.message = ""
        except ValueError as exc:
            self.message = f"refused: {' '.join(str(exc).split())}"

    def key(self, ch: str) -> str | None:
        """Handle one key; returns "accept", "abort", "changed", or None (nothing to send)."""
        self.message = ""
        if ch in ("\r", "\n"):
            return "accept"
        if ch in ("q", "Q", "\x1b", "\x03", "\x04"):
            return "abort"
        if ch in ("1", "2", "\t"):
            other = "right" if self.eye == "left" else "left"
            self.eye = {"1": "left", "2": "right"}.get(ch, other)
            return None
        if ch == "0":
            for part in ("pan", "tilt"):
                name = f"{self.eye}_{part}"
                self.trims[name] = self.start[name]
            return "changed"
        moves = {"a": ("pan", -1), "d": ("pan", 1), "s": ("tilt", -1), "w": ("tilt", 1)}
        if ch.lower() in moves:
            part, sign = moves[ch.lower()]
            self.nudge(f"{self.eye}_{part}", sign * (COARSE if ch.isupper() else 1))
            return "changed"
        if ch in ("?", "h"):
            self.message = HELP
        elif not ch.isspace():
            self.message = f"unknown key {ch!r} (? for help)"
        return None

    def status(self) -> str:
        """One status line: both eyes' trims, the selected eye marked, and any message."""

        def eye(side: str) -> str:
            mark = "▶" if side == self.eye else " "
            pan, tilt = self.trims[f"{side}_pan"], self.trims[f"{side}_tilt"]
            return f"{mark}{side} pan {pan:+6.2f}° tilt {tilt:+6.2f}°"

        text = f"{eye('left')}  {eye('right')}  step {self.step_deg:g}°"
        return f"{text}  {self.message}" if self.message else text


# -- key sources ----------------------------------------------------------------------------------
def stream_keys(text: str) -> Iterator[str]:
    """Keys from a string (stdin on a pipe): each character one key, arrows decoded."""
    i = 0
    while i < len(text):
        if text[i] == "\x1b" and text[i + 1 : i + 3] in ARROWS:
            yield ARROWS[text[i + 1 : i + 3]]
            i += 3
            continue
        yield text[i]
        i += 1


def terminal_keys(fd: int) -> Iterator[str]:
    """Keys from a terminal in cbreak mode (Ctrl-C still interrupts); arrows decoded."""
    import termios
    import tty

    saved = termios.tcgetattr(fd)
    tty.setcbreak(fd, termios.TCSANOW)  # keep keys typed ahead (TCSAFLUSH would drop them)
    try:
        while True:
            data = os.read(fd, 1)
            if not data:
                return
            ch = data.decode(errors="replace")
            if ch == "\x1b":
                seq = b""
                while len(seq) < 2 and select.select([fd], [], [], 0.05)[0]:
                    seq += os.read(fd, 1)
                if seq.decode(errors="replace") in ARROWS:
                    ch = ARROWS[seq.decode()]
                elif seq:
                    continue  # some other escape sequence (F keys, …): ignore it
            yield ch
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


# -- the dialogue ---------------------------------------------------------------------------------
def run_keys(
    session: TrimSession,
    keys: Iterable[str],
    apply: Callable[[EyesCalibration], None],
    show: Callable[[str], None] | None,
) -> EyesTrims:
    """Feed keys to the session, sending the trimmed neutral after each change, until Enter."""
    for ch in keys:
        action = session.key(ch)
        if action == "accept":
            return EyesTrims(**session.trims)
        if action == "abort":
            raise CalibrationAbortedError("calibration quit by the operator; nothing written")
        if action == "changed":
            apply(session.calibration)
        if show is not None:
            show(session.status())
    raise CalibrationAbortedError("the input ended before Enter; nothing written")


def parse_set(spec: str) -> dict[str, float]:
    """`left_pan=+1.5,right_tilt=-0.02rad` → {servo: deg}; `ValueError` naming the bad part."""
    out: dict[str, float] = {}
    for part in filter(None, (p.strip() for p in spec.split(","))):
        name, eq, value = part.partition("=")
        name, value = name.strip(), value.strip().lower()
        if not eq or name not in SERVO_NAMES:
            raise ValueError(
                f"--set {part!r}: expected NAME=DEG with NAME one of {', '.join(SERVO_NAMES)}"
            )
        if name in out:
            raise ValueError(f"--set names {name} twice")
        scale = 1.0
        for suffix, factor in (("rad", math.degrees(1.0)), ("deg", 1.0), ("°", 1.0)):
            if value.endswith(suffix):
                value, scale = value[: -len(suffix)].strip(), factor
                break
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"--set {part!r}: {value!r} is not a number") from None
        if not math.isfinite(number):
            raise ValueError(f"--set {part!r}: must be finite")
        out[name] = number * scale
    if not out:
        raise ValueError("--set needs at least one NAME=DEG")
    return out


def write_trims(out: Path, trims: EyesTrims, base: EyesCalibration, where: str) -> None:
    """Write the trims file atomically, then load it back as the service will (must pass)."""
    header = (
        f"Eyes servo trims (deg added to each servo's angle), written by `{PROG}`\n"
        f"with {where}. Load with `nod eyes --trims FILE` (and `nod eyes point --trims FILE`);\n"
        f"each |trim| <= {MAX_TRIM_DEG:g} deg, centre 90 + trim within the servo's limits. "
        f"See docs/hardware.md."
    )
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.write_text(trims_toml(trims, header))
    try:
        load_and_apply(base, tmp)
    except ConfigError:
        tmp.unlink(missing_ok=True)
        raise
    tmp.replace(out)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod eyes calibrate`."""
    p = Parser(
        prog=PROG,
        description="Centre each eye servo (trims) by eye and write the trims file `nod eyes "
        "--trims` loads. Interactive on a terminal; --set or keys on stdin for scripts.",
        epilog=HELP,
    )
    bench.add_bench_args(p)
    p.add_argument("--out", type=Path, required=True, help="trims file to write (TOML)")
    p.add_argument(
        "--set",
        dest="set_spec",
        default=None,
        metavar="NAME=DEG,...",
        help="set trims without keys, e.g. left_pan=+1.5,right_pan=-0.5 (deg; 'rad' suffix ok)",
    )
    p.add_argument(
        "--step", type=float, default=0.5, help="trim step of one key press (deg, default 0.5)"
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log the driver at debug level")
    return p


def _show_on_terminal(status: str) -> None:
    print(f"\r\x1b[K{status}", end="", flush=True)


def calibrate(
    driver: ServoDriver, out: Path, set_values: dict[str, float] | None, step_deg: float
) -> EyesTrims:
    """The whole dialogue on a connected driver; returns the trims written."""
    base = driver.calibration
    session = TrimSession(base, step_deg)

    def apply(calib: EyesCalibration) -> None:
        driver.calibration = calib
        driver.neutral()

    start = driver.neutral()
    try:
        if set_values is not None:
            for name, value in set_values.items():
                session.set(name, value)
            trims = EyesTrims(**session.trims)
        elif sys.stdin.isatty():
            print(f"Calibrating {bench.describe(driver)}: neutral gaze, trims live.\n{HELP}")
            show = _show_on_terminal
            show(session.status())
            try:
                trims = run_keys(session, terminal_keys(sys.stdin.fileno()), apply, show)
            finally:
                print()
        else:
            trims = run_keys(session, stream_keys(sys.stdin.read()), apply, None)
        driver.calibration = session.calibration
        bench.settle(driver, driver.neutral(), start)
    except (CalibrationAbortedError, KeyboardInterrupt):
        driver.calibration = base
        with contextlib.suppress(bench.BenchError):
            bench.settle(driver, driver.neutral(), None, timeout_s=1.0)
        raise
    write_trims(out, trims, base, bench.describe(driver))
    return trims


def main(argv: list[str] | None = None) -> int:
    """Run the calibration; 2 on bad input, an unusable port or a quit; 1 if the device fails."""
    p = build_parser()
    args = p.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    if not (math.isfinite(args.step) and 0 < args.step <= MAX_TRIM_DEG):
        p.error(f"--step must be in (0, {MAX_TRIM_DEG:g}] deg, got {args.step}")
    try:
        set_values = parse_set(args.set_spec) if args.set_spec is not None else None
        driver = bench.open_driver(args)
    except (ValueError, bench.BenchError) as exc:
        return fail(PROG, exc)
    with bench.sigterm_as_interrupt():
        try:
            trims = calibrate(driver, args.out, set_values, args.step)
        except (ValueError, CalibrationAbortedError) as exc:
            return fail(PROG, exc)
        except bench.BenchError as exc:
            print(f"{PROG}: {exc}; nothing written", file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            print(f"\n{PROG}: interrupted; nothing written", file=sys.stderr)
            return 130
        finally:
            driver.disconnect()
    text = ", ".join(f"{n} {v:+.2f}°" for n, v in trims.as_dict().items())
    print(f"wrote {args.out}: {text}")
    return 0
