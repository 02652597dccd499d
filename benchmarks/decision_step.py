"""Decision hot path: the model step per hand pose, and decoding a pose, against baselines.

1. `DecisionModel.on_hand` (observer + RK4 of eq 1 and eq 6 through `opinion_rate` and
   `bias_rate`, the functions the analysis and the tests use) against a baseline that is the
   same engine with eq 1 and eq 6 written inline in the RK4 loop (the code before the model
   had one home; kept here only as the speed reference). Same poses, same results checked.
2. `messages.decode(HandPose, …)` (msgspec, every strict check) against a bare
   `msgpack.unpackb` of the same payload (parsing only, no validation at all).

Poses are a 21-landmark hand reaching with 2 px jitter, at 30 and 120 Hz, in dissensus and
consensus trials. Interleaved rounds, best of each. Exit 1 if the model step costs more than
`--max-ratio` (default 1.2) times the inline baseline at 120 Hz, or the results differ.

    .venv/bin/python benchmarks/decision_step.py [--rounds 7]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import msgpack
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.core import messages as m  # noqa: E402
from services.model.bias import beta_for, sigma_for  # noqa: E402
from services.model.decision import DecisionModel  # noqa: E402


class InlineBaseline(DecisionModel):
    """The same engine with eqs 1 and 6 written out inside the loop (no function calls)."""

    def _integrate(self, span_ns: int, z_hat: float) -> None:
        robot = self.params.pair.robot
        d, u, alpha = robot.d, robot.u, robot.alpha
        coupling = robot.gamma * self.params.pair.a_rh * z_hat
        tanh = math.tanh
        consensus = self.mode == "consensus"
        option = self.option or "red"
        sigma, beta = sigma_for(option, self.params.bias), beta_for(option, self.params.bias)
        b_star, b_max = self.b_star, self.params.bias.b_max
        sgn = 1.0 if z_hat > 0 else -1.0
        z_r, b_r = self._z_r, self._b_r
        n_full, rest_ns = divmod(span_ns, self._dt_ns)
        steps = [self._dt_ns * 1e-9] * n_full
        if rest_ns:
            steps.append(rest_ns * 1e-9)
        for h in steps:
            hh = 0.5 * h
            k1z = -d * z_r + u * tanh(alpha * z_r + coupling) + b_r
            if consensus and z_r * z_hat < 0:
                k1b = sigma * z_r * sgn + beta * max(0.0, b_star - abs(b_r))
                z2, b2 = z_r + hh * k1z, b_r + hh * k1b
                k2z = -d * z2 + u * tanh(alpha * z2 + coupling) + b2
                k2b = sigma * z2 * sgn + beta * max(0.0, b_star - abs(b2))
                z3, b3 = z_r + hh * k2z, b_r + hh * k2b
                k3z = -d * z3 + u * tanh(alpha * z3 + coupling) + b3
                k3b = sigma * z3 * sgn + beta * max(0.0, b_star - abs(b3))
                z4, b4 = z_r + h * k3z, b_r + h * k3b
                k4z = -d * z4 + u * tanh(alpha * z4 + coupling) + b4
                k4b = sigma * z4 * sgn + beta * max(0.0, b_star - abs(b4))
                b_r += (h / 6.0) * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)
                b_r = max(-b_max, min(b_max, b_r))
            else:
                k2z = -d * (z_r + hh * k1z) + u * tanh(alpha * (z_r + hh * k1z) + coupling) + b_r
                k3z = -d * (z_r + hh * k2z) + u * tanh(alpha * (z_r + hh * k2z) + coupling) + b_r
                k4z = -d * (z_r + h * k3z) + u * tanh(alpha * (z_r + h * k3z) + coupling) + b_r
            z_r += (h / 6.0) * (k1z + 2.0 * k2z + 2.0 * k3z + k4z)
        self._z_r, self._b_r = z_r, b_r


def poses(hz: float, n: int = 2400) -> list[tuple[int, list[tuple[float, float]]]]:
    rng = np.random.default_rng(1)
    out, x, y = [], 0.5, 0.85
    for i in range(n):
        x, y = x - 0.3 / hz, y - 0.3 / hz
        if x < 0.2:
            x, y = 0.5, 0.85
        pts = rng.normal((x, y), 0.003, (21, 2))
        out.append((round(i * 1e9 / hz), [(float(a), float(b)) for a, b in pts]))
    return out


def per_pose_us(cls: type[DecisionModel], stream, mode: str) -> tuple[float, float, float]:
    model = cls()
    model.reset(mode, "blue" if mode == "consensus" else None)
    t0 = time.perf_counter()
    for t, lm in stream:
        model.on_hand(t, lm)
    return (time.perf_counter() - t0) / len(stream) * 1e6, model.z_r, model.b_r


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--max-ratio", type=float, default=1.2)
    args = ap.parse_args()
    ok = True
    print(f"{'case':<22} {'baseline µs':>12} {'model µs':>9} {'ratio':>6}")
    for hz in (30.0, 120.0):
        stream = poses(hz)
        for mode in ("dissensus", "consensus"):
            base, new = [], []
            for _ in range(args.rounds):  # interleaved: both see the same machine state
                base.append(per_pose_us(InlineBaseline, stream, mode))
                new.append(per_pose_us(DecisionModel, stream, mode))
            b, n = min(r[0] for r in base), min(r[0] for r in new)
            same = base[0][1:] == new[0][1:]
            ratio = n / b
            print(f"{f'{hz:.0f} Hz {mode}':<22} {b:>12.2f} {n:>9.2f} {ratio:>6.2f}"
                  f"{'' if same else '  RESULTS DIFFER'}")
            ok &= same and (hz < 100 or ratio <= args.max_ratio)
    lm = tuple((0.5 + i * 0.001, 0.6) for i in range(21))
    payload = m.encode(m.HandPose(seq=1, t_ns=2, detected=True, center=(0.51, 0.6), landmarks=lm))
    raw, strict = [], []
    for _ in range(args.rounds):
        t0 = time.perf_counter()
        for _ in range(20000):
            msgpack.unpackb(payload)
        raw.append((time.perf_counter() - t0) / 20000 * 1e6)
        t0 = time.perf_counter()
        for _ in range(20000):
            m.decode(m.HandPose, payload)
        strict.append((time.perf_counter() - t0) / 20000 * 1e6)
    print(f"hand pose decode: msgpack.unpackb {min(raw):.2f} µs, strict decode "
          f"{min(strict):.2f} µs (ratio {min(strict) / min(raw):.2f})")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
