"""What the store's integrity checks cost: opening with `quick_check`, `nod store check`, a backup.

A store of `--sessions` sessions as the conductor writes them (8 trials × 600 samples a trial,
10 s at 60 Hz, each with its 21 landmarks: ≈ 1.5 MB a session), then, best of `--rounds`
interleaved rounds with the file in the page cache:

- baseline: opening the store as before the check (connect, WAL, schema, migration), closed;
- `Store(path)`: the same plus the header/size check and `PRAGMA quick_check`, closed;
- `check_file(path, full=True)`: `nod store check`'s `PRAGMA integrity_check`;
- `Store.backup()`: the online backup, its check and the rename (what a session's end costs).

Exit 1 if the check adds more than `--max-ms-per-mb` to an open (default 5 ms per MB).

    .venv/bin/python benchmarks/store_check.py [--sessions 40] [--rounds 5]
"""

from __future__ import annotations

import argparse
import sqlite3
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.store import Store, check_file  # noqa: E402
from services.store.fits import FITS_SCHEMA  # noqa: E402
from services.store.schema import SCHEMA  # noqa: E402
from tests.unit.test_store_integrity import fill  # noqa: E402


def open_unchecked(path: Path) -> None:
    """The open as it was before the check: connect, WAL, schema (a migration has nothing to do)."""
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("PRAGMA journal_mode=WAL")
    db.execute("PRAGMA synchronous=NORMAL")
    db.execute("PRAGMA foreign_keys=ON")
    db.executescript(SCHEMA + FITS_SCHEMA)
    db.close()


def best(fn, rounds: int) -> float:
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sessions", type=int, default=40, help="sessions in the store (default 40)")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--max-ms-per-mb", type=float, default=5.0)
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="nod-store-check-") as tmp:
        path = Path(tmp) / "study.sqlite"
        t0 = time.monotonic()
        store = Store(path)
        for i in range(args.sessions):
            fill(store, f"s{i}", f"P{i + 1:02d}", seed=i)
        store.close()
        mb = path.stat().st_size / 1e6
        print(f"store: {args.sessions} sessions, {mb:.1f} MB "
              f"({path.stat().st_size // 4096} pages), written in {time.monotonic() - t0:.1f} s")
        base, checked, full, backup = [], [], [], []
        for _ in range(args.rounds):  # interleaved: a busy moment hits every variant alike
            base.append(best(lambda: open_unchecked(path), 1))
            checked.append(best(lambda: Store(path).close(), 1))
            full.append(best(lambda: check_file(path, full=True), 1))

            def back_up() -> None:
                s = Store(path)
                s.backup()
                s.close()

            backup.append(best(back_up, 1) - checked[-1])
        b, c, f, k = min(base), min(checked), min(full), min(backup)
        added = c - b
        print(f"open without the check   {b * 1e3:8.1f} ms")
        print(f"open with quick_check    {c * 1e3:8.1f} ms  (+{added * 1e3:.1f} ms, "
              f"{added * 1e3 / mb:.2f} ms per MB)")
        print(f"nod store check (full)   {f * 1e3:8.1f} ms")
        print(f"backup at a session end  {k * 1e3:8.1f} ms")
    ok = added * 1e3 / mb <= args.max_ms_per_mb
    print("PASS" if ok else f"FAIL: the check adds more than {args.max_ms_per_mb} ms per MB")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
