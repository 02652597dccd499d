"""What every `nod` command line shares: one-line errors, the session flags, `--params`, `-v`."""

from __future__ import annotations

import argparse
import math
import re
import sys
from pathlib import Path
from typing import NoReturn


class Parser(argparse.ArgumentParser):
    """argparse whose errors are one line on stderr (no usage dump), with exit code 2."""

    def error(self, message: str) -> NoReturn:
        """Print `prog: error: message` on one line and exit 2."""
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")


def one_line(text: str, limit: int | None = 300) -> str:
    """An error for one line of stderr: whitespace folded, zenoh's Rust locations gone, cut short.

    `limit` characters at most (None: the whole text).
    """
    text = re.sub(r"\s*\bat \S+\.rs:\d+\.?", "", " ".join(text.split()))
    return text if limit is None or len(text) <= limit else text[:limit] + "…"


def fail(prog: str, message: object) -> int:
    """Say what is wrong in one line on stderr, `prog: message`; return 2, a bad input's code."""
    print(f"{prog}: {one_line(str(message), limit=None)}", file=sys.stderr)
    return 2


def finite_float(text: str) -> float:
    """An argparse type: a finite number (biases, angles)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0 (durations, rates, speeds)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a number > 0, got {text!r}")
    return value


def add_params_arg(parser: argparse.ArgumentParser) -> None:
    """Add `--params FILE.toml` (SPEC defaults when absent)."""
    parser.add_argument(
        "--params",
        type=Path,
        default=None,
        metavar="FILE.toml",
        help="experiment parameters overriding SPEC defaults (see deploy/params.example.toml)",
    )


def add_service_args(parser: argparse.ArgumentParser) -> None:
    """Every service's common flags: zenoh session, shared clock, `--params`, `-v`."""
    from services.core.clock import add_clock_args
    from services.core.session import add_zenoh_args

    add_zenoh_args(parser)
    add_clock_args(parser)
    add_params_arg(parser)
    parser.add_argument("-v", "--verbose", action="store_true", help="log at debug level")
