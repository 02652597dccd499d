"""What every `nod` command line shares: one-line errors, session flags, `--params`, `--options`."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import NoReturn

from services.core.text import one_line
from services.model.schedule import MAX_OPTIONS

__all__ = ["one_line"]  # re-exported: the commands take it from here with the other helpers


class Parser(argparse.ArgumentParser):
    """argparse whose errors are one line on stderr (no usage dump), with exit code 2."""

    def error(self, message: str) -> NoReturn:
        """Print `prog: error: message` on one line and exit 2."""
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")


def fail(prog: str, message: object) -> int:
    """Say what is wrong in one line on stderr, `prog: message`; return 2, a bad input's code."""
    print(f"{prog}: {one_line(str(message), limit=None)}", file=sys.stderr)
    return 2


def print_report(
    report: object, lines: Iterable[str], as_json: bool, out: Callable[[str], object] = print
) -> None:
    """A command's report: one JSON document (`--json`), else its lines for a person."""
    if as_json:
        out(json.dumps(report, ensure_ascii=False))
    else:
        for line in lines:
            out(line)


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


MAX_SEED = 2**63 - 1  # seeds are non-negative (numpy refuses < 0) and an int64 everywhere


def int_in(low: int, high: int | None = None) -> Callable[[str], int]:
    """An argparse type: a whole number in [low, high] (no upper bound if None).

    Every integer flag goes through one of these: a count of 0, a negative port or a seed numpy
    refuses is a one-line usage error at the command line, not a traceback later.
    """
    span = f"in [{low}, {high}]" if high is not None else f">= {low}"

    def parse(text: str) -> int:
        try:
            value = int(text, 10)
        except ValueError:
            why = f"must be a whole number {span}, got {text!r}"
            raise argparse.ArgumentTypeError(why) from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"must be {span}, got {value}")
        return value

    parse.__name__ = "int"  # argparse names the type in its messages
    return parse


def host_port(text: str) -> tuple[str, int]:
    """`HOST:PORT` (`[::1]:8090` for IPv6; port 0: any free one) as (host, port); ValueError."""
    host, colon, port = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not colon or not host or not port.isdigit() or int(port) > 65535:
        raise ValueError(f"{text!r} is not HOST:PORT such as 127.0.0.1:8090 (port 0: any free)")
    return host, int(port)


SEED = int_in(0, MAX_SEED)
PORT = int_in(1, 65535)


def add_params_arg(parser: argparse.ArgumentParser) -> None:
    """Add `--params FILE.toml` (SPEC defaults when absent)."""
    parser.add_argument(
        "--params",
        type=Path,
        default=None,
        metavar="FILE.toml",
        help="experiment parameters overriding SPEC defaults (see deploy/params.example.toml)",
    )


def add_options_arg(parser: argparse.ArgumentParser) -> None:
    """Add `--options N`: a table of N boxes (default: the params file's, else the paper's 2).

    Read with `services.core.config.load_with_options`, which checks it against the file.
    """
    parser.add_argument(
        "--options", type=int_in(2, MAX_OPTIONS), default=None, metavar="N",
        help="options (boxes) on the table: 2 is the paper's study (default), 3 or more run "
        "the N-option rig (docs/multi-option.md); a params file may list them instead",
    )


def fabric_parser(prog: str, description: str, epilog: str | None = None) -> Parser:
    """The command line of a command that talks to a rig over Zenoh (`add_zenoh_args` on it)."""
    from services.core.session import add_zenoh_args

    parser = Parser(prog=prog, description=description, epilog=epilog)
    add_zenoh_args(parser)
    return parser


def service_parser(
    prog: str, description: str, epilog: str | None = None, options: bool = False
) -> Parser:
    """The command line every long-running service starts from, its common flags on it.

    Its name and what it does, then `add_service_args`: the fabric, the shared clock,
    `--params` and `-v`, and `--options N` for a service that reads the table (`options`);
    the service adds its own flags after.
    """
    parser = Parser(prog=prog, description=description, epilog=epilog)
    add_service_args(parser)
    if options:
        add_options_arg(parser)
    return parser


def add_service_args(parser: argparse.ArgumentParser) -> None:
    """Every service's common flags: zenoh session, shared clock, `--params`, `-v`."""
    from services.core.clock import add_clock_args
    from services.core.session import add_zenoh_args

    add_zenoh_args(parser)
    add_clock_args(parser)
    add_params_arg(parser)
    parser.add_argument("-v", "--verbose", action="store_true", help="log at debug level")
