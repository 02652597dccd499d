"""`nod report`: the per-trial results of a session, from its SQLite file."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from services.core.cli import Parser
from services.store import Store


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
    if not args.db.is_file():
        print(f"nod report: no such database: {args.db}", file=sys.stderr)
        return 2
    store = Store(args.db)
    try:
        trials = store.trials(args.session)
    finally:
        store.close()
    if args.session is not None and not trials:
        print(f"nod report: no trials for session {args.session!r}", file=sys.stderr)
        return 2
    rows = [
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
        }
        for session, t in trials
    ]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for r in rows:
        print(
            f"{r['trial']:>3} {r['mode']:<10} {r['option'] or '-':<5} robot={r['robot'] or '-':<5}"
            f" human={r['human'] or '-':<5} {r['outcome'] or '-':<3} switches={r['switches']}"
            f" violations={r['violations']} score={r['score']}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
