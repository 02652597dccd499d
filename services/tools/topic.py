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
import math
import re
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import msgspec
import zenoh

from services.core import messages as m
from services.core.cli import Parser, positive_float
from services.core.contract import TOPICS
from services.core.keys import check_rig
from services.core.node import clip, install_signal_handlers
from services.core.session import Fabric, add_zenoh_args, open_session
from services.core.tap import POLL_S, QUEUE_MAX, Arrival, Tap  # noqa: F401 (re-exported)

PROG = "nod topic"
REPORT_S = 1.0  # `hz` prints once per second


class ToolError(Exception):
    """Bad input or an unreachable rig: one line on stderr, exit 2."""


# --- keys ---------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Target:
    """What a KEY argument names: the key expression to subscribe to and the topics it covers."""

    expr: str  # e.g. nod/rig1/vision/hand, nod/rig1/safety/*
    topics: tuple[str, ...]  # the contract topics it matches

    @property
    def is_pattern(self) -> bool:
        """True if the expression has wildcards (it may match several keys)."""
        return "*" in self.expr or "$" in self.expr


def resolve(key: str, rig: str) -> Target:
    """The key expression of a KEY argument (full, or relative to `rig`); ToolError if unknown."""
    text = key.strip().strip("/")
    if text == "nod" or text.startswith("nod/"):
        parts = text.split("/", 2)
        if len(parts) < 3 or not parts[2]:
            raise ToolError(f"key {key!r} names no topic: give nod/<rig>/<topic> or a topic, "
                            "e.g. vision/hand")
        _, rig, name = parts
        if rig != "*":
            try:
                check_rig(rig)
            except ValueError as exc:
                raise ToolError(str(exc)) from None
    else:
        name = text
    if not name:
        raise ToolError("empty key: give a topic, e.g. vision/hand")
    if "*" in name or "$" in name:
        try:
            pattern = zenoh.KeyExpr(name)
        except zenoh.ZError as exc:
            raise ToolError(f"{key!r} is not a key expression: {clean(str(exc))}") from None
        topics = tuple(t for t in TOPICS if pattern.intersects(zenoh.KeyExpr(t)))
    else:
        topics = (name,) if name in TOPICS else ()
    if not topics:
        raise ToolError(
            f"unknown key {key!r}: the contract's keys (nod/<rig>/...) are {', '.join(TOPICS)}"
        )
    return Target(f"nod/{rig}/{name}", topics)


def topic_of(key: str) -> str | None:
    """The contract topic of a full key of any rig (`nod/<rig>/<topic>`), or None."""
    parts = key.split("/", 2)
    if len(parts) == 3 and parts[0] == "nod" and parts[2] in TOPICS:
        return parts[2]
    return None


def decode(key: str, payload: bytes) -> m.Message:
    """The message on a full key, strictly validated; MessageError says why not."""
    topic = topic_of(key)
    if topic is None:
        raise m.MessageError("not a key of the contract: no decoder")
    return m.decode(TOPICS[topic].message, payload)


def clean(text: str) -> str:
    """One short line of a zenoh error: the message itself, without the Rust source locations."""
    inner = re.search(r'msg: "(.*?)"', text)  # a config error wraps its text in Json5Err(...)
    if inner:
        text = inner.group(1)
    text = re.sub(r"\s*\bat \S+\.rs:\d+\.?", "", text)
    return clip(text, 300)


# --- rates --------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Stats:
    """The arrival rate of some messages and the spread of the intervals between them."""

    count: int  # messages
    rate_hz: float
    min_s: float
    max_s: float
    std_s: float

    def describe(self) -> str:
        """`50.0 Hz  min 19.6 ms  max 20.4 ms  std 0.21 ms`."""
        return (
            f"{self.rate_hz:.1f} Hz  min {_ms(self.min_s)}  max {_ms(self.max_s)}  "
            f"std {_ms(self.std_s)}"
        )

    def as_json(self) -> dict[str, Any]:
        """The statistics as a JSON object."""
        return {
            "count": self.count,
            "rate_hz": round(self.rate_hz, 3),
            "min_ms": round(self.min_s * 1e3, 3),
            "max_ms": round(self.max_s * 1e3, 3),
            "std_ms": round(self.std_s * 1e3, 3),
        }


def _ms(seconds: float) -> str:
    ms = seconds * 1e3
    return f"{ms:.1f} ms" if ms >= 10 else f"{ms:.2f} ms"


def interval_stats(times: Iterable[float]) -> Stats | None:
    """Statistics of arrival times (ascending); None with fewer than two."""
    times = list(times)
    if len(times) < 2 or times[-1] <= times[0]:
        return None
    gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
    mean = (times[-1] - times[0]) / len(gaps)
    std = math.sqrt(sum((g - mean) ** 2 for g in gaps) / len(gaps))
    return Stats(len(times), 1.0 / mean, min(gaps), max(gaps), std)


class Rate:
    """Arrivals of one key: the last `window` arrival times, and running totals of every one."""

    def __init__(self, window: int = 100) -> None:
        self.recent: deque[float] = deque(maxlen=max(2, window))
        self.count = 0
        self.first: float | None = None
        self.last: float | None = None
        self._gaps = 0
        self._mean = 0.0  # Welford's running mean and sum of squares of the intervals
        self._m2 = 0.0
        self._min = math.inf
        self._max = 0.0

    def add(self, t: float) -> None:
        """Record an arrival at monotonic time `t`."""
        if self.last is None:
            self.first = t
        else:
            gap = max(0.0, t - self.last)
            self._gaps += 1
            delta = gap - self._mean
            self._mean += delta / self._gaps
            self._m2 += delta * (gap - self._mean)
            self._min = min(self._min, gap)
            self._max = max(self._max, gap)
        self.last = t
        self.count += 1
        self.recent.append(t)

    def window(self) -> Stats | None:
        """Statistics of the last `window` arrivals."""
        return interval_stats(self.recent)

    def total(self) -> Stats | None:
        """Statistics of every arrival so far."""
        if self._gaps == 0 or self._mean <= 0:
            return None
        std = math.sqrt(self._m2 / self._gaps)
        return Stats(self.count, 1.0 / self._mean, self._min, self._max, std)


# --- the command line ---------------------------------------------------------------------------


def _int_at_least(low: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = low - 1
        if value < low:
            raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {text!r}")
        return value

    return parse


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
    ls.add_argument(
        "--duration", type=positive_float, default=2.0, metavar="S",
        help="seconds to listen (2)",
    )
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
        "-n", "--count", type=_int_at_least(1), default=None, metavar="N",
        help="stop after N valid messages",
    )
    echo.add_argument(
        "--duration", type=positive_float, default=None, metavar="S",
        help="stop after S seconds",
    )
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
    hz.add_argument(
        "--duration", type=positive_float, default=None, metavar="S",
        help="stop after S seconds (default: Ctrl-C)",
    )
    hz.add_argument(
        "--window", type=_int_at_least(2), default=100, metavar="W",
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
        print(f"{PROG} {args.action}: {exc}", file=sys.stderr)
        return 2


def connect(args: argparse.Namespace) -> zenoh.Session:
    """The session the flags describe; ToolError (one line) if it cannot open."""
    try:
        fabric = Fabric.from_args(args)
        return open_session(fabric.zenoh_config())
    except zenoh.ZError as exc:  # the configuration itself (open_session turns the rest into
        # ConnectionError): a malformed endpoint, a config file zenoh refuses
        raise ToolError(f"bad zenoh session flags: {clean(str(exc))}") from None
    except (ConnectionError, OSError, ValueError) as exc:
        raise ToolError(clean(str(exc))) from None


def _out(line: str) -> None:
    print(line, flush=True)


# --- list ---------------------------------------------------------------------------------------


@dataclass(slots=True)
class Seen:
    """What `list` saw on one key."""

    rate: Rate
    invalid: int = 0
    size: int = 0


def run_list(args: argparse.Namespace) -> int:
    """`nod topic list`."""
    rig = args.rig
    session = connect(args)
    stop = threading.Event()
    install_signal_handlers(stop)
    seen: dict[str, Seen] = {}
    alive: dict[str, bool] = {}
    alive_prefix = f"nod/{rig}/alive/"

    def on_alive(sample: zenoh.Sample) -> None:
        alive[str(sample.key_expr)[len(alive_prefix):]] = sample.kind == zenoh.SampleKind.PUT

    t0 = time.monotonic()
    deadline = t0 + args.duration
    try:
        tap = Tap(session, f"nod/{rig}/**")
        watch = session.liveliness().declare_subscriber(
            f"{alive_prefix}*", on_alive, history=True
        )
        try:
            while not stop.is_set() and time.monotonic() < deadline:
                item = tap.next(deadline)
                if item is None:
                    continue
                entry = seen.get(item.key)
                if entry is None:
                    entry = seen[item.key] = Seen(Rate())
                entry.rate.add(item.t)
                entry.size += len(item.payload)
                try:
                    decode(item.key, item.payload)
                except m.MessageError:
                    entry.invalid += 1
        finally:
            tap.close()
            watch.undeclare()
    finally:
        session.close()
    elapsed = min(time.monotonic(), deadline) - t0
    report = list_report(rig, elapsed, seen, sorted(s for s, up in alive.items() if up))
    report["dropped"] = tap.dropped
    if args.json:
        _out(json.dumps(report, ensure_ascii=False))
    else:
        for line in list_lines(report):
            _out(line)
    return 0


def list_report(
    rig: str, elapsed: float, seen: dict[str, Seen], alive: list[str]
) -> dict[str, Any]:
    """The JSON form of `list`: every contract key (seen or silent) and every other key seen."""
    rows: list[dict[str, Any]] = []
    for name, spec in TOPICS.items():
        key = f"nod/{rig}/{name}"
        if spec.queried_only and key not in seen:  # answers queries; nothing to hear on it
            continue
        rows.append(_row(key, name, seen.get(key), elapsed) | {
            "message": spec.message.__name__,
            "publishers": list(spec.publishers),
            "subscribers": list(spec.subscribers),
            "declared_rate": spec.rate,
            "qos": spec.qos.describe(),
        })
    known = {row["key"] for row in rows}
    for key in sorted(set(seen) - known):
        rows.append(_row(key, None, seen[key], elapsed))
    return {"rig": rig, "duration_s": round(elapsed, 3), "keys": rows, "alive": alive}


def _row(key: str, topic: str | None, entry: Seen | None, elapsed: float) -> dict[str, Any]:
    count = entry.rate.count if entry else 0
    stats = entry.rate.total() if entry else None
    rate = stats.rate_hz if stats else (count / elapsed if count and elapsed > 0 else None)
    return {
        "key": key,
        "topic": topic,
        "in_contract": topic is not None,
        "seen": count > 0,
        "count": count,
        "rate_hz": None if rate is None else round(rate, 3),
        "invalid": entry.invalid if entry else 0,
        "bytes": entry.size if entry else 0,
    }


def list_lines(report: dict[str, Any]) -> list[str]:
    """The text form of `list`: a table of the keys seen, then the silent ones, then who is up."""
    rows = report["keys"]
    seen = [r for r in rows if r["seen"]]
    silent = [r for r in rows if not r["seen"]]
    header = ("KEY", "MSGS", "RATE", "MESSAGE", "PUBLISHERS", "DECLARED RATE")

    def cells(r: dict[str, Any]) -> tuple[str, ...]:
        rate = "-" if r["rate_hz"] is None else f"{r['rate_hz']:.1f} Hz"
        if r["invalid"]:
            rate += f" ({r['invalid']} invalid)"
        if not r["in_contract"]:
            return (r["key"], str(r["count"]), rate, "(not in the contract)", "", "")
        who = r["publishers"]
        if len(who) > 3:  # e.g. a heartbeat every service sends
            who = [*who[:2], f"... (+{len(who) - 2})"]
        return (r["key"], str(r["count"]), rate, r["message"], ", ".join(who), r["declared_rate"])

    table = [header] + [cells(r) for r in seen + silent]
    widths = [max(len(row[i]) for row in table) for i in range(len(header))]

    def fmt(row: tuple[str, ...]) -> str:
        right = {1, 2}  # counts and rates align right
        out = [
            c.rjust(w) if i in right else c.ljust(w)
            for i, (c, w) in enumerate(zip(row, widths, strict=True))
        ]
        return "  ".join(out).rstrip()

    lines = [
        f"rig {report['rig']!r}: listened {report['duration_s']:.1f} s on nod/{report['rig']}/**; "
        f"{len(seen)} key(s) seen, {len(silent)} silent",
        fmt(header),
    ]
    lines += [fmt(cells(r)) for r in seen]
    if silent:
        lines.append(f"silent (in the contract, nothing in {report['duration_s']:.1f} s):")
        lines += [fmt(cells(r)) for r in silent]
    alive = report["alive"]
    lines.append(f"alive: {', '.join(alive)}" if alive else "alive: no liveliness token seen")
    if report.get("dropped"):
        lines.append(f"({report['dropped']} samples dropped: the tool fell behind)")
    return lines


# --- echo ---------------------------------------------------------------------------------------


def run_echo(args: argparse.Namespace) -> int:
    """`nod topic echo KEY`."""
    target = resolve(args.key, args.rig)
    session = connect(args)
    stop = threading.Event()
    install_signal_handlers(stop)
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
                    _out(invalid_line(item.key, item.payload, str(exc), args.json))
                    continue
                _out(json_line(item.key, msg) if args.json else text_line(item.key, msg))
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
        if len(value) > 4 and all(isinstance(v, tuple) for v in value):
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
    session = connect(args)
    stop = threading.Event()
    install_signal_handlers(stop)
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
                    _out(hz_line(rate, reported))
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
    _out(hz_summary(target.expr, rate, elapsed, invalid, tap.dropped))
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
