"""Calibration speed: one CMA-ES generation on a local Dask cluster of 1 and of 2 workers, and
`nod cohort --participants 300` end to end.

A generation is what `nod calibrate-cohort` computes per step: `--popsize` candidates (pycma's
default for the fitted traits) × `--participants` simulated people, one batch on the engine.
Baseline: the same generation on a cluster of 1 worker, in the same run; the speed-up is
1-worker time / 2-worker time (ideal: 2 on 2 free cores). Each cluster is started before its
clock starts (start-up is reported apart), and the generation is timed best of `--repeat`.
Then `nod cohort --participants 300 --quiet` (samples stored, as by default) runs as its own
process: wall time, cluster start and stop included, against the issue's 60 s on 2 cores.

Exit status 1 if the speed-up is below `--min-speedup` (default 1.5) or the cohort takes more
than `--max-cohort-s` (default 60).

    .venv/bin/python benchmarks/bench_calibration.py [--participants 32] [--repeat 2]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from services.cohort.outcomes import (  # noqa: E402
    cohort_outcomes,
    flows,
    session_outcomes,
    shares,
)
from services.cohort.person import load_cohort_params  # noqa: E402
from services.compute.engine import open_engine  # noqa: E402
from services.sim.fit import TRAITS, CohortObjective, default_popsize, to_unit  # noqa: E402


def session_cpu(job: tuple) -> float:
    """One session's CPU seconds on its worker (to tell a slow machine from a loaded one)."""
    t = time.process_time()
    session_outcomes(job)
    return time.process_time() - t


def generation_seconds(workers: int, popsize: int, participants: int, repeat: int) -> tuple:
    """(cluster start s, best generation s, CPU s per session) on a local cluster of `workers`."""
    cfg = load_cohort_params(None)
    t0 = time.perf_counter()
    with open_engine(workers=workers) as engine:
        start = time.perf_counter() - t0
        own = cohort_outcomes(engine, cfg, 1, participants)
        objective = CohortObjective(engine, cfg, shares(own), flows(own), participants, 1)
        rng = np.random.default_rng(7)
        x0 = to_unit(cfg)
        candidates = [np.clip(x0 + rng.normal(0, 0.2, x0.size), 0, 1) for _ in range(popsize)]
        best = float("inf")
        for _ in range(repeat):
            t = time.perf_counter()
            objective(candidates)
            best = min(best, time.perf_counter() - t)
        cpu = engine.map(session_cpu, [(cfg, seed) for seed in range(1, 1 + 4 * workers)])
    return start, best, sum(cpu) / len(cpu)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--participants", type=int, default=32, help="per candidate (32)")
    ap.add_argument("--popsize", type=int, default=default_popsize(len(TRAITS)))
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--cohort", type=int, default=300, help="nod cohort --participants (300)")
    ap.add_argument("--min-speedup", type=float, default=1.5)
    ap.add_argument("--max-cohort-s", type=float, default=60.0)
    args = ap.parse_args()

    sessions = args.popsize * args.participants
    print(f"one generation: {args.popsize} candidates x {args.participants} participants = "
          f"{sessions} sessions")
    times = {}
    for workers in (1, 2):
        start, best, cpu = generation_seconds(workers, args.popsize, args.participants,
                                              args.repeat)
        times[workers] = best
        # busy: the share of the workers' wall time spent computing (< 1: the cores are shared)
        busy = sessions * cpu / (best * workers)
        print(f"  {workers} worker{'s' if workers > 1 else ' '}: {best:6.1f} s "
              f"({sessions / best:5.1f} sessions/s; {cpu:.3f} CPU s per session, workers busy "
              f"{busy:.0%}; cluster start {start:.1f} s)")
    speedup = times[1] / times[2]
    print(f"  speed-up 2 vs 1 workers: {speedup:.2f}x")

    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        res = subprocess.run(
            [sys.executable, "-m", "services.cli", "cohort", "--participants", str(args.cohort),
             "--db", str(Path(tmp) / "c.sqlite"), "--quiet"],
            cwd=ROOT, capture_output=True, text=True,
        )
        wall = time.perf_counter() - t
    if res.returncode != 0:
        print(res.stderr, file=sys.stderr)
        return 1
    print(f"nod cohort --participants {args.cohort}: {wall:.1f} s wall "
          f"(target <= {args.max_cohort_s:.0f} s): {res.stdout.strip()}")
    ok = speedup >= args.min_speedup and wall <= args.max_cohort_s
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
