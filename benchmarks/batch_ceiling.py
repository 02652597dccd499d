"""What vectorising the closed loop across people can gain while it equals the per-person loop.

Issue 35 (item 7) asks for the offline loop run as NumPy over a batch of sessions, with the
same outcomes as the per-person loop for the same seeds. The loop's arithmetic is mostly RK4
stages (eq 1 in the decision engine, 1000 steps per simulated second; eq 2 in the person, 500),
four `tanh` each. `+ − × ÷` are IEEE-exact in NumPy and in Python alike, but the transcendental
functions are not: NumPy's `tanh` (SIMD) and Python's `math.tanh` (the C library's) disagree in
the last bit for about a third of arguments on this machine, and `exp`, `expm1`, `acos` and
`hypot` differ too (`hypot`: Python's own algorithm). A batch that must equal the per-person
loop bit for bit therefore has to call the C library's `tanh` once per element.

This measures, on the decision engine's own RK4 kernel (`DecisionModel._run`: eq 1 and eq 6
with the bias controller on, the paper's kernel), per person and step:

- **Baseline**: `DecisionModel._run` per person (plain floats, what the loop runs today);
- **exact batch**: the same RK4 over B people as NumPy arrays, `tanh` = `math.tanh` per element
  (the only exact choice); its result is checked equal to the baseline's, bit for bit;
- **NumPy batch**: the same with `np.tanh` (the speed a batch could have), and how many of its
  people end on other bits than the baseline.

Each at several batch sizes: NumPy's ~1 µs per call is shared by the batch, so the arrays pay
only over hundreds of people at once. Also printed: the share of random arguments where
`np.tanh` ≠ `math.tanh`. The batch kernel is kept here only as the measuring stick (the
decision engine's `_run` is the code; docs/scale.md says what a whole batched loop gave).
Exit 1 if the exact batch does not equal the baseline.

    .venv/bin/python benchmarks/batch_ceiling.py [--people 128,512,2048] [--steps 34] [--rounds 5]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.model.decision import DecisionModel  # noqa: E402

Tanh = Callable[[np.ndarray], np.ndarray]


def libm_tanh(x: np.ndarray) -> np.ndarray:
    """`math.tanh` of every element: the per-person loop's bits."""
    return np.fromiter(map(math.tanh, x.tolist()), float, len(x))


def batch_run(
    model: DecisionModel, z_r: np.ndarray, b_r: np.ndarray, z_hat: np.ndarray, n: int, h: float,
    tanh: Tanh,
) -> tuple[np.ndarray, np.ndarray]:
    """`DecisionModel._run` over arrays of people (consensus), the same operations in order.

    The bias's branch is chosen per person and step (`np.where`); a frozen person's stage
    biases are its b_r, which is what the frozen branch adds. `max(0, v)` is `where(v > 0, v,
    0)`, as Python's max returns its first argument on a tie (the sign of a zero kept).
    """
    robot = model.params.pair.robot
    nd, u, alpha = -robot.d, robot.u, robot.alpha
    gz = robot.gamma * model.params.pair.a_rh * z_hat
    sigma, beta, b_star = model._sigma, model._beta, model.b_star
    b_max = model.params.bias.b_max
    sgn = np.where(z_hat > 0, 1.0, -1.0)
    hh, h6 = 0.5 * h, h / 6.0

    def rate_b(z: np.ndarray, b: np.ndarray) -> np.ndarray:
        room = b_star - np.abs(b)
        return sigma * z * sgn + beta * np.where(room > 0.0, room, 0.0)

    for _ in range(n):
        on = z_r * z_hat < 0
        k1z = nd * z_r + u * tanh(alpha * z_r + gz) + b_r
        k1b = rate_b(z_r, b_r)
        z2, b2 = z_r + hh * k1z, np.where(on, b_r + hh * k1b, b_r)
        k2z = nd * z2 + u * tanh(alpha * z2 + gz) + b2
        k2b = rate_b(z2, b2)
        z3, b3 = z_r + hh * k2z, np.where(on, b_r + hh * k2b, b_r)
        k3z = nd * z3 + u * tanh(alpha * z3 + gz) + b3
        k3b = rate_b(z3, b3)
        z4, b4 = z_r + h * k3z, np.where(on, b_r + h * k3b, b_r)
        k4z = nd * z4 + u * tanh(alpha * z4 + gz) + b4
        k4b = rate_b(z4, b4)
        b_new = b_r + h6 * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)
        b_new = np.where(b_new > b_max, b_max, np.where(b_new < -b_max, -b_max, b_new))
        b_r = np.where(on, b_new, b_r)
        z_r = z_r + h6 * (k1z + 2.0 * k2z + 2.0 * k3z + k4z)
    return z_r, b_r


def best(fn: Callable[[], object], rounds: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(rounds):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def measure(b: int, n: int, rounds: int, rng: np.random.Generator) -> tuple[float, ...]:
    """(baseline, exact batch, NumPy batch) s per person-step, exact's equality, people off."""
    h = 1e-3
    z_r, b_r = rng.normal(0.0, 1.0, b), rng.normal(0.0, 2.0, b)
    z_hat = rng.normal(0.0, 4.0, b)
    model = DecisionModel()
    model.reset("consensus", "red")

    def per_person() -> tuple[list[float], list[float]]:
        out = [model._run(z, bb, zh, n, h)
               for z, bb, zh in zip(z_r.tolist(), b_r.tolist(), z_hat.tolist(), strict=True)]
        return [o[0] for o in out], [o[1] for o in out]

    t_base, base = best(per_person, rounds)
    t_exact, exact = best(lambda: batch_run(model, z_r, b_r, z_hat, n, h, libm_tanh), rounds)
    t_np, fast = best(lambda: batch_run(model, z_r, b_r, z_hat, n, h, np.tanh), rounds)

    def bits(values: object) -> list[str]:
        return [float(v).hex() for v in np.ravel(np.asarray(values))]

    same = float(bits(exact) == bits(base))
    off = sum(a != c for a, c in zip(bits(fast), bits(base), strict=True)) / 2
    per = 1.0 / (b * n)
    return t_base * per, t_exact * per, t_np * per, same, off


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--people", default="128,512,2048", help="batch sizes, comma-separated")
    parser.add_argument("--steps", type=int, default=34, help="1 ms steps (34: one 30 Hz pose)")
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    rng = np.random.default_rng(35)
    ok = True
    print(f"RK4 of eq 1 and eq 6 (consensus), {args.steps} steps, ns per person-step, best of "
          f"{args.rounds}:")
    print(f"{'people':>7} {'baseline':>9} {'exact batch':>12} {'ratio':>6} {'equal':>6} "
          f"{'np.tanh batch':>14} {'ratio':>6} {'people off':>11}")
    for b in (int(x) for x in args.people.split(",")):
        base, exact, fast, same, off = measure(b, args.steps, args.rounds, rng)
        ok = ok and bool(same)
        print(f"{b:>7} {base * 1e9:>9.0f} {exact * 1e9:>12.0f} {base / exact:>5.2f}× "
              f"{'yes' if same else 'NO':>6} {fast * 1e9:>14.0f} {base / fast:>5.1f}× "
              f"{off:>7.0f} of {b}")
    x = rng.normal(0.0, 2.0, 200_000)
    print(f"np.tanh ≠ math.tanh on {float(np.mean(np.tanh(x) != libm_tanh(x))):.1%} of N(0, 2) "
          "arguments")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
