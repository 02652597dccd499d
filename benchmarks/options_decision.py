"""The N-option decision engine's step per hand pose: the float loop against NumPy's.

    .venv/bin/python benchmarks/options_decision.py [--rounds 5] [--min-ratio 2]

Per 30 Hz pose (33 RK4 steps of 1 ms), three options, a consensus trial with the controller
running (ẑ_h held on another option than O) and a dissensus one:

- **Baseline**: the same scheme on NumPy vectors of three, its rates `general_rates`
  (`tests/unit/robot_oracle.py`, the tests' reference);
- **Candidate**: `services.model.decision.rk4_robot` (the scheme on floats), which
  `OptionsDecision` runs;
- also printed: the paper's two-option `DecisionModel._integrate` over the same span (the
  engine the N-option one should come near), and the largest difference between candidate and
  baseline (must be ≤ 1e-12).

Exits 1 when the candidate is not `--min-ratio` times faster than the baseline (best of
`--rounds`), or disagrees.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from services.model.decision import (
    DecisionModel,  # noqa: E402
    rk4_robot,  # noqa: E402
)
from services.model.dynamics import OptionsParams, option_vector  # noqa: E402
from tests.unit.robot_oracle import numpy_rk4_robot  # noqa: E402

POSES = 60
STEPS = [0.001] * 33 + [1 / 30 - 0.033]


def best_of(rounds: int, run: Callable[[], object]) -> float:
    """The fastest of `rounds` runs, in seconds per pose."""
    best = float("inf")
    for _ in range(rounds):
        t0 = time.perf_counter()
        run()
        best = min(best, (time.perf_counter() - t0) / POSES)
    return best


def main() -> int:
    """Run the benchmark; 0 when the float loop is fast enough and agrees."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--min-ratio", type=float, default=2.0)
    args = p.parse_args()
    params = OptionsParams(n_options=3)
    ok = True
    print(f"{'trial':<10} {'numpy ms':>9} {'floats ms':>9} {'ratio':>6} {'paper ms':>9} "
          f"{'max |diff|':>10}")
    for mode, option in (("consensus", 0), ("dissensus", None)):
        z_hat = 0.8 * option_vector(1, 3)

        def run(step: Callable[..., tuple[np.ndarray, float]]) -> tuple[np.ndarray, float]:
            z, s = np.zeros(3), 0.0
            for _ in range(POSES):
                z, s = step(z, s, z_hat, STEPS, params, option)  # noqa: B023
            return z, s

        base = best_of(args.rounds, lambda: run(numpy_rk4_robot))  # noqa: B023
        cand = best_of(args.rounds, lambda: run(rk4_robot))  # noqa: B023
        (zb, sb), (zc, sc) = run(numpy_rk4_robot), run(rk4_robot)
        diff = max(float(np.max(np.abs(zb - zc))), abs(sb - sc))
        paper = DecisionModel()
        paper.reset(mode, "red" if option is not None else None)  # type: ignore[arg-type]
        span_ns = round(1e9 / 30)

        def run_paper() -> None:
            for _ in range(POSES):
                paper._integrate(span_ns, -0.8)  # noqa: B023

        two = best_of(args.rounds, run_paper)
        ratio = base / cand
        ok &= ratio >= args.min_ratio and diff <= 1e-12
        print(f"{mode:<10} {base * 1e3:>9.3f} {cand * 1e3:>9.3f} {ratio:>6.1f} "
              f"{two * 1e3:>9.3f} {diff:>10.1e}")
    verdict = "met" if ok else "MISSED"
    print(f"goal: floats ≥ {args.min_ratio:.1f}× numpy, agreeing to 1e-12: {verdict}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
