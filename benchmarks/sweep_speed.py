"""Sweep speed: `nod analyze sweep` against a plain vectorised RK4 baseline, same run, same grid.

Baseline: `services.analysis.sweep.sweep_rk4`, every grid point integrated with classical RK4
at dt = 5 ms over 20 s, measured in this process (compute only: no interpreter start-up, no
imports, no file output — the comparison is tilted toward the baseline).
Candidate: the whole CLI process `python -m services.cli analyze sweep --grid N --range R
--out tmp.npz`, wall time, best of `--repeat`. Also reported: the fast solver's in-process
compute time (best of `--repeat`), and whether the CLI's map equals the baseline's.

Exit status 1 if the ratio baseline / CLI is below `--min-ratio` (default 5) or the consensus
maps differ or z differs by more than 1e-6 where the baseline converged.

    .venv/bin/python benchmarks/sweep_speed.py [--grid 121] [--range 6] [--repeat 3]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.analysis.sweep import bias_grid, sweep, sweep_rk4  # noqa: E402
from services.core.lifeline import nod_command  # noqa: E402
from services.model.dynamics import PairParams  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", type=int, default=121)
    ap.add_argument("--range", type=float, default=6.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--min-ratio", type=float, default=5.0)
    args = ap.parse_args()

    p = PairParams()
    b = bias_grid(args.grid, args.range)

    t0 = time.perf_counter()
    base = sweep_rk4(b, b, p)
    t_base = time.perf_counter() - t0
    print(
        f"baseline  RK4 dt=5 ms, 20 s, {args.grid}x{args.grid} (in-process compute): {t_base:.3f} s"
    )

    compute = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        sweep(b, b, p)
        compute.append(time.perf_counter() - t0)
    print(
        f"fast      solver compute (in-process, best of {args.repeat}):      {min(compute):.3f} s"
    )

    walls = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "tmp.npz"
        cmd = nod_command(
            "analyze", "sweep", "--grid", str(args.grid), "--range", str(args.range),
            "--out", str(out), "--no-progress",
        )
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True)
            walls.append(time.perf_counter() - t0)
        with np.load(out) as data:
            same_map = bool(np.array_equal(data["consensus"], base.consensus))
            ok = base.converged
            z_err = float(
                max(
                    np.abs(data["z_r"] - base.z_r)[ok].max(initial=0.0),
                    np.abs(data["z_h"] - base.z_h)[ok].max(initial=0.0),
                )
            )
    wall = min(walls)
    ratio = t_base / wall
    print(f"candidate `nod analyze sweep` process wall time (best of {args.repeat}): {wall:.3f} s")
    print(f"ratio baseline / CLI process: {ratio:.1f}x (goal >= {args.min_ratio:g}x)")
    print(
        f"agreement: consensus maps identical = {same_map}; "
        f"max |z - z_baseline| where baseline converged = {z_err:.2e} "
        f"({int(ok.sum())}/{ok.size} converged)"
    )
    if ratio < args.min_ratio or not same_map or z_err > 1e-6:
        print("FAIL", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
