"""`nod clicks`: enter or correct a stored trial's counter clicks, and rescore it.

The conductor stores each trial the moment it ends, its clicks "not entered", and asks the
operator after (`nod experiment --clicks prompt`). An answer not given then — a Ctrl-C at the
prompt, a lost terminal, `--clicks none`, a count corrected from the paper sheet — is entered
here: the trial's clicks and its points change, nothing else.

    nod clicks --db study.sqlite --session 3f2a9c1d0b7e --trial 4 --count 10
    nod clicks --db study.sqlite --session 3f2a9c1d0b7e --trial 4 --not-entered
"""

from __future__ import annotations

import argparse
from pathlib import Path

from services.core.cli import Parser, fail, int_in
from services.model.scoring import points_said
from services.store import Store, StoreError


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod clicks`."""
    p = Parser(prog="nod clicks", description=__doc__.splitlines()[0])
    p.add_argument("--db", type=Path, required=True, help="the session store")
    p.add_argument("--session", required=True, help="the session (`nod report` lists them)")
    p.add_argument("--trial", type=int_in(1, 10_000), required=True, help="the trial number")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--count", type=int_in(0, 100_000), help="the clicks the participant "
                      "counted (the target is the session's, 10 by default)")
    what.add_argument("--not-entered", action="store_true",
                      help="clear the clicks: the counter task is unknown (no point either way)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Set the clicks, print the trial's new points; 0 on success, 2 on a bad input."""
    args = build_parser().parse_args(argv)
    try:
        store = Store.existing(args.db)
    except StoreError as exc:
        return fail("nod clicks", exc)
    count = None if args.not_entered else args.count
    try:
        before = {t.trial: t for _, t in store.trials(args.session)}.get(args.trial)
        record = store.set_clicks(args.session, args.trial, count)
        target = store.target_clicks(args.session)
    except StoreError as exc:
        return fail("nod clicks", exc)
    finally:
        store.close()
    was = "not entered" if before is None or before.clicks is None else str(before.clicks)
    now = "not entered" if record.clicks is None else str(record.clicks)
    said = points_said(record.human, record.robot, record.violations, record.clicks, target)
    print(f"session {args.session} trial {args.trial}: clicks {was} → {now}; {said} "
          f"(was {before.score if before else '?'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
