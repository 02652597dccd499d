"""The offline loop's hottest numeric kernel, compiled with Numba: the same floats, faster.

A cohort (`nod cohort`, `nod calibrate-cohort`, `nod analyze power`, the fit's reference
table) runs the offline closed loop once per simulated person, and must give the same sessions
for the same seeds whatever runs it (tests/unit/test_golden.py, the stored rows' SHA-256 of
benchmarks/cohort_speed.py). The decision engine's RK4 of eq 1 and eq 6
(`DecisionModel._run`, ~33 steps of 1 ms per camera frame) was a fifth of a session's CPU, the
rest of it Python's boxed floats around four `math.tanh` a step. Here the same steps are one
machine-code loop.

Why these are the same bits as the Python loop:

- `+ − × ÷`, comparisons, `abs` and `copysign` are IEEE operations, correctly rounded in both.
- `math.tanh` compiles to a call of the C library's `tanh`, which is what CPython's
  `math.tanh` calls (NumPy's SIMD `tanh` is another algorithm and differs in the last bit).
- No `fastmath`: LLVM may then neither reassociate nor contract a product and a sum into one
  fused multiply-add (an FMA rounds once where Python rounds twice), so every operation is
  rounded where Python rounds it, in the order written.
- Python's `max(0.0, m)` keeps 0.0 unless m > 0.0 (a −0.0 or a NaN m gives +0.0); it is
  written as that comparison, not as a `max` whose tie rule could pick −0.0.

tests/unit/test_loop_speed.py holds the compiled kernel to `DecisionModel._run` bit for bit
(`float.hex`, so a zero's sign counts) and whole sessions to the Python engine's.

Compiled once per process on first use (~0.5 s), then cached on disk next to this file
(`cache=True`: a Dask worker or a test process loads it in milliseconds). Only the offline
loop uses it (`closed_loop`); the rig's decision service keeps the Python `_run`, so no live
service imports Numba or waits for a compiler. `NOD_NO_JIT=1` runs the offline loop on the
Python kernel too (same results, slower).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from typing import cast

RK4Pair = Callable[
    [float, float, float, int, float, float, float, float, float, bool, float, float, float,
     float],
    tuple[float, float],
]


def rk4_pair(
    z_r: float,
    b_r: float,
    z_hat: float,
    n: int,
    h: float,
    nd: float,
    u: float,
    alpha: float,
    gz: float,
    consensus: bool,
    sigma: float,
    beta: float,
    b_star: float,
    b_max: float,
) -> tuple[float, float]:
    """Take n RK4 steps of h of eqs 1 and 6 from (z_r, b_r), ẑ_h held: `DecisionModel._run`.

    The same operations in the same order as `_run` (its docstring says why they are written
    out; −d, γ_r a_rh ẑ_h are hoisted there as `nd`, `gz`), stopped at an exact fixed point of
    the step as `_run` stops. Plain Python: Numba compiles this very function (`pair_kernel`).
    """
    tanh = math.tanh
    copysign = math.copysign
    sgn = 1.0 if z_hat > 0 else -1.0
    hh, h6 = 0.5 * h, h / 6.0
    for _ in range(n):
        z0, b0 = z_r, b_r
        k1z = nd * z_r + u * tanh(alpha * z_r + gz) + b_r
        if consensus and z_r * z_hat < 0:
            m = b_star - abs(b_r)
            k1b = sigma * z_r * sgn + beta * (m if m > 0.0 else 0.0)
            z2, b2 = z_r + hh * k1z, b_r + hh * k1b
            k2z = nd * z2 + u * tanh(alpha * z2 + gz) + b2
            m = b_star - abs(b2)
            k2b = sigma * z2 * sgn + beta * (m if m > 0.0 else 0.0)
            z3, b3 = z_r + hh * k2z, b_r + hh * k2b
            k3z = nd * z3 + u * tanh(alpha * z3 + gz) + b3
            m = b_star - abs(b3)
            k3b = sigma * z3 * sgn + beta * (m if m > 0.0 else 0.0)
            z4, b4 = z_r + h * k3z, b_r + h * k3b
            k4z = nd * z4 + u * tanh(alpha * z4 + gz) + b4
            m = b_star - abs(b4)
            k4b = sigma * z4 * sgn + beta * (m if m > 0.0 else 0.0)
            b_r += h6 * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)
            if b_r > b_max:
                b_r = b_max
            elif b_r < -b_max:
                b_r = -b_max
        else:
            z2 = z_r + hh * k1z
            k2z = nd * z2 + u * tanh(alpha * z2 + gz) + b_r
            z3 = z_r + hh * k2z
            k3z = nd * z3 + u * tanh(alpha * z3 + gz) + b_r
            z4 = z_r + h * k3z
            k4z = nd * z4 + u * tanh(alpha * z4 + gz) + b_r
        z_r += h6 * (k1z + 2.0 * k2z + 2.0 * k3z + k4z)
        if (
            z_r == z0
            and b_r == b0
            and copysign(1.0, z_r) == copysign(1.0, z0)
            and copysign(1.0, b_r) == copysign(1.0, b0)
        ):
            break
    return z_r, b_r


_compiled: RK4Pair | None = None


def pair_kernel() -> RK4Pair:
    """`rk4_pair` compiled (once per process; the Python function under NOD_NO_JIT=1)."""
    global _compiled
    if _compiled is None:
        if os.environ.get("NOD_NO_JIT") == "1":
            _compiled = rk4_pair
        else:
            from numba import njit  # imported here: only the offline loop pays for it

            _compiled = cast(RK4Pair, njit(cache=True, nogil=True)(rk4_pair))
    return _compiled
