"""`nod topic list`: every key of a rig seen for a while, the contract's silent keys, who is up."""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from typing import Any

import zenoh

from services.core.cli import print_report
from services.core.contract import TOPICS
from services.tools.observe import Rate, Window, listen, print_line


@dataclass(slots=True)
class Seen:
    """What `list` saw on one key."""

    rate: Rate
    invalid: int = 0
    size: int = 0


def run_list(args: argparse.Namespace) -> int:
    """`nod topic list`."""
    rig = args.rig
    session, stop = listen(args)
    seen: dict[str, Seen] = {}
    alive: dict[str, bool] = {}
    alive_prefix = f"nod/{rig}/alive/"

    def on_alive(sample: zenoh.Sample) -> None:
        alive[str(sample.key_expr)[len(alive_prefix):]] = sample.kind == zenoh.SampleKind.PUT

    t0 = time.monotonic()
    deadline = t0 + args.duration
    try:
        with Window(session, f"nod/{rig}/**", f"{alive_prefix}*", on_alive) as window:
            for item, msg in window.heard(deadline, stop):
                entry = seen.get(item.key)
                if entry is None:
                    entry = seen[item.key] = Seen(Rate())
                entry.rate.add(item.t)
                entry.size += len(item.payload)
                if msg is None:
                    entry.invalid += 1
    finally:
        session.close()
    elapsed = min(time.monotonic(), deadline) - t0
    report = list_report(rig, elapsed, seen, sorted(s for s, up in alive.items() if up))
    report["dropped"] = window.tap.dropped
    print_report(report, list_lines(report), args.json, print_line)
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
