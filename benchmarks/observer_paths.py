"""Observer modes on realistic hand paths: wrong-side frames, spurious switches, added latency.

The paths (services/analysis/observer_eval.py) are made independently of the simulated
participant: minimum-jerk reaches on the paper's table — straight, with a pause, with a sag
back, a change of mind with a sideways leg, from an off-centre start, slow — each toward both
boxes, seen at 640×480 with 1, 2 and 3 px of common landmark jitter (plus 0.5 px each), at 30
and 60 Hz, several seeds. The baseline is the paper's Algorithm 1 (mode "paper") on the same
frames. Exit 1 if the default (robust) mode misses a target: wrong-side frames ≤ 1%, spurious
switches ≤ 0.1 per reach, added latency ≤ 150 ms (median and 90th percentile).

    .venv/bin/python benchmarks/observer_paths.py [--seeds 5]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.analysis.observer_eval import evaluate  # noqa: E402
from services.model.observer import ObserverParams  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args()
    print(f"{'mode':<7} {'Hz':>3} {'wrong side':>10} {'spurious/reach':>14} "
          f"{'added latency med / p90':>24}  worst path")
    ok = True
    for mode in ("paper", "robust"):
        for hz in (30.0, 60.0):
            s = evaluate(ObserverParams(mode=mode), hz, seeds=args.seeds)
            added = f"{s.added_median * 1e3:.0f} / {s.added_p90 * 1e3:.0f} ms"
            print(f"{mode:<7} {hz:>3.0f} {s.wrong_frac * 100:>9.2f}% {s.spurious_per_reach:>14.3f} "
                  f"{added:>24}  {s.worst_path}")
            if mode == "robust":
                ok &= s.wrong_frac <= 0.01 and s.spurious_per_reach <= 0.1
                ok &= s.added_median <= 0.15 and s.added_p90 <= 0.15
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
