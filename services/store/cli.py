"""`nod store check`: a session store's full integrity check, one line per problem.

Every command that opens a store runs SQLite's quick check first and refuses a damaged file
(`services.store.store`); this is the full one (`PRAGMA integrity_check`: the b-trees, and every
index against its table), on a read-only connection, for the operator's "what is wrong with it?"
and for a lab's nightly check of its stores and their backups.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from services.core.cli import Parser, fail
from services.store.store import MAX_PROBLEMS, backup_path, check_file

DAMAGED = 1  # exit code of a store that fails its check (2: the command was given bad input)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod store`."""
    p = Parser(prog="nod store", description="The session store's maintenance.")
    sub = p.add_subparsers(dest="verb", required=True, metavar="check")
    check = sub.add_parser(
        "check",
        help="SQLite's full integrity check of a store (exit 0: ok; 1: damaged)",
        description="SQLite's full integrity check (PRAGMA integrity_check) of each store, on a "
        "read-only connection: `FILE: ok`, or one line per problem (at most "
        f"{MAX_PROBLEMS} a file). Exit 0 when every file is ok, 1 when one is damaged.",
    )
    check.add_argument("--db", type=Path, action="append", required=True, metavar="FILE",
                       help="the store (repeat for several: each rig's, a backup)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run `nod store check`."""
    args = build_parser().parse_args(argv)
    code = 0
    for path in args.db:
        if not path.is_file():
            return fail("nod store check", f"no such database: {path}")
        t0 = time.monotonic()
        try:
            problems = check_file(path, full=True, limit=MAX_PROBLEMS - 1)
        except OSError as exc:
            return fail("nod store check", exc)
        if not problems:
            size = path.stat().st_size
            print(f"{path}: ok ({size / 1e6:.1f} MB checked in {time.monotonic() - t0:.2f} s)")
            continue
        code = DAMAGED
        for problem in problems:
            print(f"{path}: {problem}")
        backup = backup_path(path)
        if backup.is_file():
            print(f"{path}: DAMAGED: its last backup is {backup} (`nod store check --db "
                  f"{backup}` checks it)")
        else:
            print(f"{path}: DAMAGED: no backup ({backup}) beside it")
    return code


if __name__ == "__main__":
    raise SystemExit(main())
