"""`nod cohort --participants 300` end to end, against the pure cost of its sessions (same run).

- **Baseline**: `--baseline` sessions (seeds 1, 2, …) of the default simulated person run one
  after the other in this process — `run_offline_session(cfg, seed, cohort=True, record=True)`,
  exactly what each cohort task computes — as CPU seconds per session: the model's own cost,
  with no engine, no store, no interpreter start. Twice: on the Python parts (`NOD_NO_JIT=1`,
  the loop as the rig's services step it) and on the compiled ones (`services.model.compiled`,
  what the cohort runs; after one warm-up session that loads or compiles them, timed apart),
  and the sessions compared trial by trial.
- **Candidate**: `nod cohort --participants N --seed 1 --db TMP --quiet` as its own process:
  wall time (the embedded Dask cluster's start and stop included), and the CPU seconds of that
  process and its workers together (RUSAGE_CHILDREN) per session. Run again with `--small`
  participants, the two walls tell the cost paid once a cohort (interpreter, cluster, the
  workers' first imports) from the rate once started, and project a 5,000-person table.

Also printed: the ideal wall time (N × baseline ÷ cores), the overhead above it, the load
average before and after (a timing is valid only on a quiet machine: below ~1.5, and no
/tmp/nod-quiet, the lead's load-test flag), and the SHA-256 of every stored row (sessions,
trials, samples): a speed-up must not change it for the same seeds, so compare it between
commits. CPU seconds stay meaningful under load; wall time does not.

Exit status 1 if the cohort takes more than `--max-s` (default 60, issue 21's goal); 3 if the
compiled parts give other sessions than the Python parts.

    .venv/bin/python benchmarks/cohort_speed.py [--participants 300] [--baseline 12]
"""

from __future__ import annotations

import argparse
import hashlib
import math
import os
import resource
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.cohort.person import load_cohort_params  # noqa: E402
from services.core.lifeline import nod_command  # noqa: E402
from services.model.closed_loop import run_offline_session  # noqa: E402

QUIET_FLAG = Path("/tmp/nod-quiet")
GOAL_PER_MIN = 3000  # issue 35: simulated sessions a minute on two cores, once started


def load() -> str:
    """The 1-minute load average, and a note when the machine is not quiet."""
    one = os.getloadavg()[0]
    notes = [
        n for n, bad in (("load test running", QUIET_FLAG.exists()), ("loaded", one >= 1.5)) if bad
    ]
    return f"{one:.2f}" + (f" ({', '.join(notes)}: wall times not valid)" if notes else "")


def baseline_cpu(sessions: int, python: bool) -> tuple[float, list[str]]:
    """CPU seconds per session of the cohort's task in this process, and the sessions' reprs.

    `python`: on the Python parts (NOD_NO_JIT=1), else on the compiled ones.
    """
    cfg = load_cohort_params(None)
    os.environ["NOD_NO_JIT"] = "1" if python else "0"
    try:
        t0 = time.process_time()
        runs = [repr(run_offline_session(cfg, seed, cohort=True, record=True))
                for seed in range(1, sessions + 1)]
        return (time.process_time() - t0) / sessions, runs
    finally:
        os.environ.pop("NOD_NO_JIT")


def warm_up() -> float:
    """Wall seconds to load (or compile) the compiled parts: one session, not timed with them."""
    t0 = time.perf_counter()
    run_offline_session(load_cohort_params(None), 10**6, cohort=True, record=True)
    return time.perf_counter() - t0


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def stored_digest(db: Path) -> str:
    """SHA-256 of every row of the store's sessions, trials and samples, in insertion order."""
    digest = hashlib.sha256()
    with sqlite3.connect(db) as con:
        for table in ("sessions", "trials", "samples"):
            for row in con.execute(f"SELECT * FROM {table} ORDER BY rowid"):  # noqa: S608
                digest.update(repr(row).encode())
    return digest.hexdigest()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--participants", type=int, default=300)
    parser.add_argument("--small", type=int, default=20,
                        help="the second, small cohort that tells the fixed cost from the rate")
    parser.add_argument("--baseline", type=int, default=12, help="in-process sessions")
    parser.add_argument("--workers", type=int, default=None, help="default: one per core")
    parser.add_argument("--max-s", type=float, default=60.0, help="goal for the cohort's wall")
    args = parser.parse_args()
    cores = args.workers or os.cpu_count() or 1

    print(f"load before: {load()}")
    python, plain = baseline_cpu(args.baseline, python=True)
    print(f"baseline, Python parts: {python:.4f} CPU s per session in process "
          f"({args.baseline} sessions; {60 / python:.0f} sessions/min per core)")
    print(f"compiled parts' warm-up (load or compile, first session): {warm_up():.2f} s")
    base, fast = baseline_cpu(args.baseline, python=False)
    print(f"baseline, compiled parts: {base:.4f} CPU s per session ({60 / base:.0f}/min per "
          f"core): {python / base:.2f}x; sessions {'identical' if fast == plain else 'DIFFER'}")
    if fast != plain:
        return 3

    small = run_cohort(args.small, args.workers)
    big = run_cohort(args.participants, args.workers)
    if small is None or big is None:
        return 2
    wall, cpu, digest = big

    n = args.participants
    ideal = n * base / cores
    print(
        f"cohort: {wall:.1f} s wall for {n} participants on {cores} cores; "
        f"{cpu / n:.3f} CPU s per session with engine and store "
        f"({cpu / n / base:.2f}× the baseline's {base:.3f})"
    )
    print(f"ideal (N × compiled baseline / cores): {ideal:.1f} s; overhead {wall - ideal:.1f} s; "
          f"{n / wall * 60:.0f} sessions/min with the engine's start and stop")
    # Wall = fixed + N / rate, from the two runs: the fixed part (interpreter, cluster, the
    # workers' first imports and compiled parts) is paid once a cohort, the rate every session.
    rate = (n - args.small) / (wall - small[0]) if wall > small[0] else math.inf
    fixed = small[0] - args.small / rate
    print(f"two runs ({args.small} and {n} participants): {rate * 60:.0f} sessions/min once "
          f"started ({rate * 60 / cores / (60 / base):.2f}× the compiled baseline's per core), "
          f"{fixed:.1f} s fixed a cohort; goal {GOAL_PER_MIN} sessions/min: "
          f"{'met' if rate * 60 >= GOAL_PER_MIN else 'NOT met'}; 5,000 people: about "
          f"{fixed + 5000 / rate:.0f} s (goal under 120 s)")
    print(f"stored rows sha256: {digest}")
    ok = wall <= args.max_s
    print(f"goal ≤ {args.max_s:.0f} s: {'met' if ok else 'MISSED'}")
    return 0 if ok else 1


def run_cohort(n: int, workers: int | None) -> tuple[float, float, str] | None:
    """`nod cohort` of n participants as its own process: (wall s, CPU s, stored rows' SHA)."""
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "cohort.db"
        cmd = nod_command(
            "cohort", "--participants", str(n), "--seed", "1", "--db", str(db), "--quiet",
        )
        if workers:
            cmd += ["--workers", str(workers)]
        print(f"load at start: {load()}")
        cpu0, t0 = children_cpu(), time.perf_counter()
        done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
        wall, cpu = time.perf_counter() - t0, children_cpu() - cpu0
        print(f"load after: {load()}")
        if done.returncode != 0:
            print(done.stdout + done.stderr, file=sys.stderr)
            return None
        print(done.stdout.strip())
        return wall, cpu, stored_digest(db)


if __name__ == "__main__":
    raise SystemExit(main())
