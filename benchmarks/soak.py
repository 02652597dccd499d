"""A soak run: many simulated participants through the distributed services, memory sampled.

`nod run --sim --participants N --speed 10 --db F` (every service its own process on one router;
a new sim person and conductor per participant, decision, actuation, eyes and speaker up for the
whole run) on a free loopback port. Every `--every` seconds the resident memory (VmRSS) of each
process under the run is read from /proc. Afterwards:

- memory: each long-lived process's samples after warm-up, and each per-participant process's
  peak (one value per participant after warm-up), must stay within 10 % of their lowest
  (`rig_probe.rss_verdict`). Warm-up: until participant `--warmup` (default max(2, N/10)) has
  begun: imports, zenoh's buffers and the allocator's arenas settle over the first people;
- trials: every participant has one session, complete, with its 8 trials stored: 0 lost (the
  issue's "0 trials lost": no participant's trial missing from the store). A trial the safety
  broke and the protocol repeated is not lost; one it broke on every attempt (`max_attempts`)
  is stored interrupted, with its reasons, and never scored: not lost either, but counted and
  printed with its reasons (`--strict` makes it a miss too), as are the repeats;
- store: `PRAGMA integrity_check` is "ok" and `PRAGMA foreign_key_check` finds nothing.

Prints a table per service and exits 1 on any miss.

    .venv/bin/python benchmarks/soak.py [--participants 100] [--speed 10] [--every 2]
"""

from __future__ import annotations

import argparse
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass, field

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)  # the tests' helpers, this folder's probe
from benchmarks.rig_probe import rss_kb, rss_verdict, services_of  # noqa: E402
from tests.processes import free_port  # noqa: E402

PER_PARTICIPANT = ("sim", "experiment")  # a new process for each person
TRIALS = 8


@dataclass
class StoreCheck:
    """What the run's store holds: problems (a miss), trials lost, stored interrupted, repeated."""

    problems: list[str] = field(default_factory=list)
    trials: int = 0  # stored
    lost: int = 0  # expected and missing from the store
    interrupted: list[str] = field(default_factory=list)  # stored interrupted: who, why
    repeated: list[str] = field(default_factory=list)  # broken, repeated, then whole: who, why


def store_check(db: str, participants: int) -> StoreCheck:
    """Read the run's store: integrity, every participant's session and trials."""
    con = sqlite3.connect(db)
    out = StoreCheck()
    try:
        if (ok := con.execute("PRAGMA integrity_check").fetchone()[0]) != "ok":
            out.problems.append(f"integrity_check: {ok}")
        if fk := con.execute("PRAGMA foreign_key_check").fetchall():
            out.problems.append(f"foreign_key_check: {len(fk)} rows")
        sessions = con.execute("SELECT session, participant, status FROM sessions").fetchall()
        people = {p for _, p, _ in sessions}
        if len(people) != participants or len(sessions) != participants:
            out.problems.append(
                f"{len(sessions)} sessions of {len(people)} participants stored, "
                f"{participants} expected"
            )
            out.lost += TRIALS * max(0, participants - len(people))
        for session, person, status in sessions:
            rows = con.execute(
                "SELECT trial, interrupted, attempts FROM trials WHERE session = ?", (session,)
            ).fetchall()
            stored = {trial for trial, _, _ in rows}
            out.trials += len(stored)
            why: dict[int, list[str]] = defaultdict(list)
            for trial, reason in con.execute(
                "SELECT trial, reason FROM interruptions WHERE session = ? ORDER BY t_ns",
                (session,),
            ):
                why[trial].append(reason)
            if status != "complete" or len(stored) != TRIALS:
                out.lost += max(0, TRIALS - len(stored))
                out.problems.append(
                    f"{person}: session {status}, {len(stored)}/{TRIALS} trials stored"
                )
            for trial, interrupted, attempts in sorted(rows):
                reasons = "; ".join(why.get(trial, [])[:3]) or "no interruption stored"
                if interrupted:
                    out.interrupted.append(
                        f"{person} trial {trial}: stored interrupted after {attempts} attempts "
                        f"({reasons})"
                    )
                elif attempts > 1:
                    out.repeated.append(f"{person} trial {trial}: attempt {attempts} ({reasons})")
        return out
    finally:
        con.close()


def main() -> int:
    """Run the soak; exit 1 on a miss."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--participants", type=int, default=100)
    ap.add_argument("--speed", type=float, default=10.0)
    ap.add_argument("--every", type=float, default=2.0, help="seconds between memory samples")
    ap.add_argument("--warmup", type=int, default=None, help="participants of warm-up")
    ap.add_argument("--tolerance", type=float, default=0.10)
    ap.add_argument(
        "--keep",
        default=None,
        metavar="DIR",
        help="write the store and logs to DIR (kept) instead of a temporary folder",
    )
    ap.add_argument(
        "--strict",
        action="store_true",
        help="a trial stored interrupted (broken on every attempt) is a miss too",
    )
    args = ap.parse_args()
    warmup = args.warmup if args.warmup is not None else max(2, args.participants // 10)
    folder = tempfile.TemporaryDirectory(prefix="nod-soak-")
    where = args.keep or folder.name
    os.makedirs(where, exist_ok=True)
    db = os.path.join(where, "soak.sqlite")
    cmd = [
        sys.executable,
        "-m",
        "services.cli",
        "run",
        "--sim",
        "--participants",
        str(args.participants),
        "--speed",
        repr(args.speed),
        "--db",
        db,
        "--listen",
        f"tcp/127.0.0.1:{free_port()}",
    ]
    long_lived: dict[str, list[float]] = defaultdict(list)  # after warm-up, MB
    peaks: dict[tuple[str, int], tuple[int, float]] = {}  # (service, pid) → (person, MB)
    started = time.monotonic()
    with open(os.path.join(where, "run.log"), "w") as log:
        proc = subprocess.Popen(
            cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, start_new_session=True
        )
    person = 0  # the participant running: how many conductors we have seen start
    seen: set[int] = set()
    try:
        while proc.poll() is None:
            for pid, (_, service) in services_of(proc.pid).items():
                kb = rss_kb(pid)
                if kb is None:
                    continue
                if service == "experiment" and pid not in seen:
                    seen.add(pid)
                    person += 1
                mb = kb / 1024
                if service in PER_PARTICIPANT:
                    _, peak = peaks.get((service, pid), (person, 0.0))
                    peaks[(service, pid)] = (person, max(peak, mb))
                elif person > warmup:
                    long_lived[service].append(mb)
            time.sleep(args.every)
    except KeyboardInterrupt:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(30)
        raise
    wall = time.monotonic() - started
    code = proc.returncode
    per_person: dict[str, list[float]] = defaultdict(list)
    for (service, _), (who, mb) in sorted(peaks.items(), key=lambda kv: kv[1][0]):
        if who > warmup:
            per_person[service].append(mb)
    print(
        f"{args.participants} participants at {args.speed:g}x: nod run exit {code}, "
        f"{wall / 60:.1f} min; warm-up {warmup} participants; memory sampled every "
        f"{args.every:g} s; load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}"
    )
    print(
        f"{'service':>17} {'samples':>8} {'min MB':>8} {'max MB':>8} {'last MB':>8} "
        f"{'growth':>7}  verdict"
    )
    ok = code == 0
    for name, series in [
        *sorted(long_lived.items()),
        *((f"{s} (peak)", v) for s, v in sorted(per_person.items())),
    ]:
        flat, growth = rss_verdict(series, args.tolerance)
        ok &= flat
        print(
            f"{name:>17} {len(series):>8} {min(series):8.1f} {max(series):8.1f} "
            f"{series[-1]:8.1f} {growth:7.1%}  {'flat' if flat else 'GROWS'}"
        )
    if not long_lived:
        print("no memory samples after warm-up: run more participants than --warmup")
        ok = False
    if code != 0:
        with open(os.path.join(where, "run.log")) as f:
            print("nod run's last lines:", *f.read().splitlines()[-8:], sep="\n  ")
    check = store_check(db, args.participants)
    for line in [*check.problems[:20], *check.interrupted[:20], *check.repeated[:20]]:
        print(f"store: {line}")
    miss = bool(check.problems) or (args.strict and bool(check.interrupted))
    print(
        f"store: {'integrity ok' if not check.problems else 'MISS'}; {check.trials} of "
        f"{TRIALS * args.participants} trials stored ({check.lost} lost), "
        f"{len(check.interrupted)} stored interrupted, {len(check.repeated)} repeated after an "
        f"interruption; verdict: {'PASS' if ok and not miss else 'MISS'}"
    )
    folder.cleanup()
    return 0 if ok and not miss else 1


if __name__ == "__main__":
    raise SystemExit(main())
