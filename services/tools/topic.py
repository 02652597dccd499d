"""`nod topic list | echo KEY | hz KEY`: look at a rig's keys from any host, like `ros2 topic`.

- `list` listens to `nod/<rig>/**` for a while and names every key seen (count, rate, the
  contract's message type and publishers), the contract's keys that stayed silent, keys outside
  the contract, and the services whose liveliness tokens are up.
- `echo KEY` decodes each sample with the contract's strict decoder for its key and prints one
  line per message (or one JSON object per line with `--json`). A payload that fails validation
  prints one line saying why, and the echo goes on.
- `hz KEY` prints the arrival rate once per second (over the last `--window` messages, with the
  min/max/std of the intervals) and a summary at the end; exit 1 if nothing arrived.

KEY is a full key (`nod/rig1/vision/hand`) or one relative to `--rig` (`vision/hand`); `echo`
also takes wildcards (`safety/*`, `**`). The tool only subscribes: it declares no liveliness token
and publishes nothing. Zenoh's thread only stamps the arrival time and queues the bytes (bounded;
what overflows is counted, never blocks the network), and decoding and printing happen on the
main thread, so a slow terminal cannot slow the rig (`services.core.tap.Tap`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

import msgspec

from services.core import messages as m
from services.core.cli import Parser, fail, int_in, positive_float
from services.core.node import clip
from services.core.session import add_zenoh_args
from services.core.tap import Tap
from services.tools.observe import Rate, ToolError, decode, listen, print_line, resolve
from services.tools.topic_list import run_list

PROG = "nod topic"
REPORT_S = 1.0  # `hz` prints once per second


# --- the command line ---------------------------------------------------------------------------


def add_duration(p: argparse.ArgumentParser, text: str, default: float | None = None) -> None:
    """A subcommand's `--duration S`: how long it listens."""
    p.add_argument("--duration", type=positive_float, default=default, metavar="S", help=text)


def build_parser() -> Parser:
    """The command line of `nod topic`."""
    p = Parser(
        prog=PROG,
        description="List, echo and measure the keys of a rig (it only listens).",
        epilog="KEY is a full key (nod/rig1/vision/hand) or one relative to --rig "
        "(vision/hand). Run `nod topic <action> --help` for an action's options.",
    )
    session = Parser(add_help=False)
    add_zenoh_args(session)
    sub = p.add_subparsers(
        dest="action", metavar="{list,echo,hz}", required=True, parser_class=Parser
    )

    ls = sub.add_parser(
        "list",
        parents=[session],
        help="every key seen, with its rate and contract entry; silent ones too",
        description="Listen to nod/<rig>/** and list every key seen (count, rate, message type, "
        "publishers), the contract's keys that stayed silent, and the services alive.",
    )
    add_duration(ls, "seconds to listen (2)", 2.0)
    ls.add_argument("--json", action="store_true", help="print one JSON object")
    ls.set_defaults(run=run_list)

    echo = sub.add_parser(
        "echo",
        parents=[session],
        help="print each message of a key, decoded",
        description="Print each message of KEY, decoded and validated with the contract's "
        "decoder; an invalid payload prints one line saying why. Stops after --count "
        "messages, --duration seconds, or Ctrl-C.",
    )
    echo.add_argument("key", metavar="KEY", help="e.g. vision/hand, or wildcards: 'safety/*'")
    echo.add_argument("--json", action="store_true", help="one JSON object per line")
    echo.add_argument(
        "-n", "--count", type=int_in(1), default=None, metavar="N",
        help="stop after N valid messages",
    )
    add_duration(echo, "stop after S seconds")
    echo.set_defaults(run=run_echo)

    hz = sub.add_parser(
        "hz",
        parents=[session],
        help="the rate of a key, once per second",
        description="Print the arrival rate of KEY once per second (over the last --window "
        "messages, with min/max/std of the intervals), then a summary of the whole run. "
        "Exit 1 if nothing arrived.",
    )
    hz.add_argument("key", metavar="KEY", help="one key, e.g. vision/hand")
    add_duration(hz, "stop after S seconds (default: Ctrl-C)")
    hz.add_argument(
        "--window", type=int_in(2), default=100, metavar="W",
        help="messages the per-second rate is computed over (100)",
    )
    hz.set_defaults(run=run_hz)
    return p


def main(argv: list[str] | None = None) -> int:
    """Run `nod topic <action>`; 2 on bad input or an unreachable router."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args))
    except ToolError as exc:
        return fail(f"{PROG} {args.action}", exc)


# --- echo ---------------------------------------------------------------------------------------


def run_echo(args: argparse.Namespace) -> int:
    """`nod topic echo KEY`."""
    target = resolve(args.key, args.rig)
    session, stop = listen(args)
    shown = invalid = 0
    deadline = None if args.duration is None else time.monotonic() + args.duration
    try:
        tap = Tap(session, target.expr)
        try:
            while not stop.is_set() and (args.count is None or shown < args.count):
                if deadline is not None and time.monotonic() >= deadline:
                    break
                item = tap.next(deadline)
                if item is None:
                    continue
                try:
                    msg = decode(item.key, item.payload)
                except m.MessageError as exc:
                    invalid += 1
                    print_line(invalid_line(item.key, item.payload, str(exc), args.json))
                    continue
                print_line(json_line(item.key, msg) if args.json else text_line(item.key, msg))
                shown += 1
        finally:
            tap.close()
    finally:
        session.close()
    if tap.dropped:
        print(f"{PROG} echo: {tap.dropped} samples dropped (the output fell behind)",
              file=sys.stderr)
    if shown == 0 and invalid == 0:
        waited = "" if args.duration is None else f" in {args.duration:g} s"
        print(f"{PROG} echo: nothing on {target.expr}{waited}", file=sys.stderr)
    return 0


def json_line(key: str, msg: m.Message) -> str:
    """One message as a JSON object: `key`, then the wire fields (`v`, `seq`, `t_ns`, ...)."""
    fields = msgspec.to_builtins(msg)  # bytes become base64 text
    return json.dumps({"key": key, **fields}, ensure_ascii=False, allow_nan=False)


def invalid_line(key: str, payload: bytes, why: str, as_json: bool) -> str:
    """One line saying why a payload was refused."""
    if as_json:
        return json.dumps({"key": key, "error": clip(why), "bytes": len(payload)})
    return f"{key}: INVALID payload ({len(payload)} bytes): {clip(why)}"


def text_line(key: str, msg: m.Message) -> str:
    """One message on one line: key, seq, source time, then `field=value` for each field."""
    parts = [key, f"#{msg.seq}", _clock(msg.t_ns)]
    for name in m.fields(type(msg)):
        if name not in ("seq", "t_ns"):
            parts.append(f"{name}={_value(getattr(msg, name))}")
    return " ".join(parts)


def _clock(t_ns: int) -> str:
    seconds, ns = divmod(t_ns, 1_000_000_000)
    try:
        return time.strftime("%H:%M:%S", time.localtime(seconds)) + f".{ns // 1_000_000:03d}"
    except (OverflowError, OSError, ValueError):  # a stamp far outside the calendar
        return f"t_ns={t_ns}"


def _value(value: Any) -> str:
    if isinstance(value, bool) or value is None:
        return str(value).lower() if value is not None else "none"
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, bytes):
        return f"<{len(value)} bytes>"
    if isinstance(value, tuple):
        if len(value) > 4 and all(isinstance(v, tuple) and len(v) == 2 for v in value):
            return f"<{len(value)} points>"  # hand landmarks: the JSON form has them all
        return "[" + ",".join(_value(v) for v in value) + "]"
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    return str(value)


# --- hz -----------------------------------------------------------------------------------------


def run_hz(args: argparse.Namespace) -> int:
    """`nod topic hz KEY`."""
    target = resolve(args.key, args.rig)
    if target.is_pattern:
        raise ToolError(f"hz measures one key; {args.key!r} has wildcards")
    session, stop = listen(args)
    rate = Rate(args.window)
    invalid = 0
    t0 = time.monotonic()
    deadline = None if args.duration is None else t0 + args.duration
    next_report = t0 + REPORT_S
    reported = 0
    try:
        tap = Tap(session, target.expr)
        try:
            while not stop.is_set():
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    break
                if now >= next_report:
                    print_line(hz_line(rate, reported))
                    reported = rate.count
                    next_report = max(next_report + REPORT_S, now)
                until = next_report if deadline is None else min(next_report, deadline)
                item = tap.next(until)
                if item is None:
                    continue
                rate.add(item.t)
                try:
                    decode(item.key, item.payload)
                except m.MessageError:
                    invalid += 1
        finally:
            tap.close()
    finally:
        session.close()
    elapsed = time.monotonic() - t0 if deadline is None else min(time.monotonic(), deadline) - t0
    print_line(hz_summary(target.expr, rate, elapsed, invalid, tap.dropped))
    if rate.count == 0:
        print(f"{PROG} hz: nothing arrived on {target.expr} in {elapsed:.1f} s", file=sys.stderr)
        return 1
    return 0


def hz_line(rate: Rate, reported: int) -> str:
    """The once-per-second line: the rate over the window, or why there is none."""
    if rate.count == reported:
        return "no new messages" if rate.count else "no message yet"
    stats = rate.window()
    if stats is None:
        return "1 message (a rate needs two)"
    return f"{stats.describe()}  window {stats.count}"


def hz_summary(key: str, rate: Rate, elapsed: float, invalid: int, dropped: int) -> str:
    """The last line of `hz`: every arrival of the run."""
    n = rate.count
    head = f"summary: {key}: {n} message{'s' if n != 1 else ''} in {elapsed:.1f} s"
    stats = rate.total()
    text = f"{head}, {stats.describe()}" if stats else head
    if invalid:
        text += f"; {invalid} invalid"
    if dropped:
        text += f"; {dropped} dropped by the tool"
    return text


if __name__ == "__main__":
    raise SystemExit(main())
