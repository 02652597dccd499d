"""`nod report`: the per-trial results of a session, from its SQLite file."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from services.core.cli import Parser, fail
from services.store import Store, StoreError


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod report`."""
    p = Parser(prog="nod report", description="Per-trial results of a session.")
    p.add_argument("--db", type=Path, required=True, help="session store written by nod run")
    p.add_argument("--session", default=None, help="session id (default: the latest session)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    return p


def main(argv: list[str] | None = None) -> int:
    """Print one session's trials."""
    args = build_parser().parse_args(argv)
    try:
        store = Store.existing(args.db)  # a damaged store is refused here, untouched
    except StoreError as exc:
        return fail("nod report", exc)
    try:
        trials = store.trials(args.session)
        session = trials[0][0] if trials else None
        events = store.safety_events(session) if session else []
        broken = store.interruptions(session) if session else []
    finally:
        store.close()
    if args.session is not None and not trials:
        return fail("nod report", f"no trials for session {args.session!r}")
    rows: list[dict[str, Any]] = [  # JSON objects, one per trial (--json prints them)
        {
            "session": session,
            "trial": t.trial,
            "mode": t.mode,
            "option": t.option,
            "robot": t.robot,
            "human": t.human,
            "outcome": t.outcome,
            "switches": t.switches,
            "violations": t.violations,
            "score": t.score,
            "interrupted": t.interrupted,
            "attempts": t.attempts,
            "safe_stops": sum(e.trial == t.trial and e.event == "safe_stop" for e in events),
            "estops": sum(e.trial == t.trial and e.event == "estop" for e in events),
            "end_reason": t.end_reason,
        }
        for session, t in trials
    ]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for r in rows:
        flags = " INTERRUPTED (not scored)" if r["interrupted"] else ""
        safety = f" safe_stops={r['safe_stops']} estops={r['estops']}" if r["safe_stops"] else ""
        retries = f" attempts={r['attempts']}" if r["attempts"] > 1 else ""
        print(
            f"{r['trial']:>3} {r['mode']:<10} {r['option'] or '-':<5} robot={r['robot'] or '-':<5}"
            f" human={r['human'] or '-':<5} {r['outcome'] or '-':<3} switches={r['switches']}"
            f" violations={r['violations']} score={r['score']}{retries}{safety}{flags}"
        )
    for b in broken:
        print(f"    trial {b.trial} attempt {b.attempt} interrupted: {b.reason}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
