"""Bias sweep of Fig 3a: the steady state of eqs 1-2 over a grid of (b_r, b_h) (SPEC §8).

Initial condition. Every grid point starts from the unopinionated origin with an infinitesimal
robot lean, z_r(0) = 1e-6, z_h(0) = 0 (`DEFAULT_Z0`). The exact origin is an equilibrium only
for b_r = b_h = 0 (a saddle in the dissensus regime), but on the whole diagonal b_r = b_h the
flow from the exact origin stays on the invariant line z_r = z_h (the pair's exchange symmetry)
and, for |b| below the consensus threshold, ends on a *saddle* of the full system: a consensus
that no perturbation would survive. The 1e-6 lean breaks that symmetry, so the flow leaves the
line along the saddle's unstable direction, as any real pair would; off the diagonal it changes
nothing but the last digits of the transient.

Steady state. A point has *converged* when max(|ż_r|, |ż_h|) < `tol` (default 1e-9) at the
state reported. Consensus is sgn z_r = sgn z_h (Sec 4.1), evaluated at that state, with an
opinion of magnitude ≤ `UNDECIDED` (1e-9, below the solvers' accuracy) counted as 0: an exactly
neutral steady state (e.g. a stable origin at zero bias when u < u_d*) must not take its sign
from round-off or an undecayed transient. Since the
divergence −d_r − d_h + u_r α_r s_r + u_h α_h s_h is negative whenever d > u α (Bendixson), the
flow has no periodic orbits and every trajectory settles on an equilibrium.

Two solvers give the same map:

* `sweep_rk4`: the plain baseline, classical RK4 at dt = 5 ms over a 20 s horizon, all points.
* `sweep`: integrate with a coarser RK4 step and, every `check_every` seconds, run vectorised
  Newton on the equilibrium equations (eqs 4-5) from each point's current state. A point is
  finished when Newton lands on an equilibrium z* that is stable (tr J < 0, det J > 0) *and*
  the current state lies in a ball around z* that the flow provably cannot leave: radius
  −μ₂(J(z*)) / (2L), with μ₂ the logarithmic norm and L the Lipschitz constant of J, so the
  trajectory's limit is z* itself. Other points keep integrating up to the horizon; those that
  never qualify are reported at their final integrated state, as the baseline does. A certified
  point reports its limit, so the rare slow point (near a bifurcation) that the baseline has
  not settled within the horizon counts as converged here.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from services.analysis.fields import (
    is_stable,
    jacobian_entries,
    jacobian_lipschitz,
    log_norm,
    max_rate,
    newton,
)
from services.model.dynamics import PairParams, rk4_pair

Progress = Callable[[float], None]

DEFAULT_Z0: tuple[float, float] = (1e-6, 0.0)  # (z_r(0), z_h(0)): origin + 1e-6 robot lean
BASELINE_DT = 0.005  # s, RK4 step of the baseline
FAST_DT = 0.02  # s, RK4 step of the transient phase of `sweep` (RK4 limit here ≈ 0.1 s)
HORIZON = 20.0  # s, integration horizon
TOL = 1e-9  # steady state: max(|ż_r|, |ż_h|) below this
UNDECIDED = 1e-9  # |z| at or below this counts as sgn z = 0 in the consensus map


@dataclass(frozen=True)
class SweepResult:
    """Steady states over the grid; 2-D arrays are indexed [i, j] for (b_h[i], b_r[j])."""

    b_r: np.ndarray  # (n_r,) robot biases, the map's columns
    b_h: np.ndarray  # (n_h,) human biases, the map's rows
    z_r: np.ndarray  # (n_h, n_r) steady robot opinion
    z_h: np.ndarray  # (n_h, n_r) steady human opinion
    converged: np.ndarray  # (n_h, n_r) bool: max(|ż_r|, |ż_h|) < tol at the reported state
    z0: tuple[float, float]  # initial condition (z_r(0), z_h(0))
    method: str  # "newton" (fast) or "rk4" (baseline)
    dt: float  # RK4 step used (s)
    horizon: float  # integration horizon (s)
    tol: float  # steady-state tolerance on max(|ż_r|, |ż_h|)

    @property
    def consensus(self) -> np.ndarray:
        """(n_h, n_r) bool: sgn z_r = sgn z_h at the steady state (Sec 4.1)."""
        return consensus_map(self.z_r, self.z_h)


def consensus_map(z_r: np.ndarray, z_h: np.ndarray, undecided: float = UNDECIDED) -> np.ndarray:
    """Consensus ⇔ sgn z_r = sgn z_h (paper Sec 4.1), element-wise; |z| ≤ `undecided` ⇒ sgn 0."""

    def sgn(z: np.ndarray) -> np.ndarray:
        return np.where(np.abs(z) <= undecided, 0.0, np.sign(z))

    return sgn(np.asarray(z_r)) == sgn(np.asarray(z_h))


def bias_grid(n: int, half_range: float) -> np.ndarray:
    """linspace(−R, R, N): the bias values of one axis of the sweep."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 2:
        raise ValueError(f"grid size N must be an integer >= 2, got {n!r}")
    if not (math.isfinite(half_range) and half_range > 0):
        raise ValueError(f"range R must be a finite number > 0, got {half_range!r}")
    return np.linspace(-half_range, half_range, int(n))


def _mesh(b_r: np.ndarray, b_h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    b_r = np.asarray(b_r, dtype=float)
    b_h = np.asarray(b_h, dtype=float)
    if b_r.ndim != 1 or b_h.ndim != 1 or not (b_r.size and b_h.size):
        raise ValueError("b_r and b_h must be non-empty 1-D arrays")
    if not (np.all(np.isfinite(b_r)) and np.all(np.isfinite(b_h))):
        raise ValueError("biases must be finite")
    BR, BH = np.meshgrid(b_r, b_h)  # [i, j] = (b_r[j], b_h[i])
    return BR.ravel(), BH.ravel()


def _check_run(dt: float, horizon: float, tol: float) -> int:
    for name, v in (("dt", dt), ("horizon", horizon), ("tol", tol)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
    return max(1, round(horizon / dt))


def sweep_rk4(
    b_r: np.ndarray,
    b_h: np.ndarray,
    p: PairParams,
    *,
    z0: tuple[float, float] = DEFAULT_Z0,
    dt: float = BASELINE_DT,
    horizon: float = HORIZON,
    tol: float = TOL,
    progress: Progress | None = None,
) -> SweepResult:
    """Baseline: plain vectorised RK4 of every grid point over the whole horizon."""
    steps = _check_run(dt, horizon, tol)
    br, bh = _mesh(b_r, b_h)
    z_r = np.full(br.shape, float(z0[0]))
    z_h = np.full(br.shape, float(z0[1]))
    chunk = max(1, steps // 100)
    done = 0
    while done < steps:
        n = min(chunk, steps - done)
        z_r, z_h = rk4_pair(z_r, z_h, br, bh, p, dt, n)
        done += n
        if progress is not None:
            progress(done / steps)
    conv = max_rate(z_r, z_h, br, bh, p) < tol
    return _result(b_r, b_h, z_r, z_h, conv, z0, "rk4", dt, steps * dt, tol)


def sweep(
    b_r: np.ndarray,
    b_h: np.ndarray,
    p: PairParams,
    *,
    z0: tuple[float, float] = DEFAULT_Z0,
    dt: float = FAST_DT,
    check_every: float = 0.1,
    horizon: float = HORIZON,
    tol: float = TOL,
    progress: Progress | None = None,
) -> SweepResult:
    """Fast sweep: short RK4 transients finished by Newton with a basin certificate.

    See the module docstring for the certificate. The result matches `sweep_rk4` on the
    consensus map and, wherever the baseline converged, on z to ≈ tol / |λ_slow|.
    """
    steps = _check_run(dt, horizon, tol)
    chunk = max(1, round(check_every / dt))
    br, bh = _mesh(b_r, b_h)
    total = br.size
    out_r = np.empty(total)
    out_h = np.empty(total)
    out_conv = np.zeros(total, dtype=bool)
    lip = jacobian_lipschitz(p)

    idx = np.arange(total)
    z_r = np.full(total, float(z0[0]))
    z_h = np.full(total, float(z0[1]))
    screen = _screen_bound(p, lip)
    done = 0
    while idx.size and done < steps:
        # Check every `check_every` s at first, then at geometrically growing intervals: the
        # few slow points left late cost more in per-check overhead than in integration.
        n = min(max(chunk, done // 8), steps - done)
        z_r, z_h = rk4_pair(z_r, z_h, br, bh, p, dt, n)
        done += n
        finished = _certified(z_r, z_h, br, bh, p, lip, tol, screen)
        if finished is not None:
            ok, root_r, root_h = finished
            out_r[idx[ok]] = root_r[ok]
            out_h[idx[ok]] = root_h[ok]
            out_conv[idx[ok]] = True
            keep = ~ok
            idx, z_r, z_h, br, bh = idx[keep], z_r[keep], z_h[keep], br[keep], bh[keep]
        if progress is not None:
            progress(max(done / steps, 1.0 - idx.size / total))
    if idx.size:  # never certified: report the integrated state, like the baseline
        out_r[idx] = z_r
        out_h[idx] = z_h
        out_conv[idx] = max_rate(z_r, z_h, br, bh, p) < tol
    shape = (np.size(b_h), np.size(b_r))
    return _result(b_r, b_h, out_r, out_h, out_conv, z0, "newton", dt, steps * dt, tol, shape=shape)


def _certified(
    z_r: np.ndarray,
    z_h: np.ndarray,
    b_r: np.ndarray,
    b_h: np.ndarray,
    p: PairParams,
    lip: float,
    tol: float,
    screen: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Newton from the current states; mask of points whose limit is certainly the root found.

    Only points with max(|ż_r|, |ż_h|) ≤ `screen` can be certified (see `_screen_bound`), so
    Newton runs on those alone.
    """
    near = np.flatnonzero(max_rate(z_r, z_h, b_r, b_h, p) <= screen)
    if not near.size:
        return None
    zr, zh, br, bh = z_r[near], z_h[near], b_r[near], b_h[near]
    root_r, root_h = newton(zr, zh, br, bh, p)
    with np.errstate(invalid="ignore", over="ignore"):
        j = jacobian_entries(root_r, root_h, p)
        mu = log_norm(j)
        dist = np.hypot(root_r - zr, root_h - zh)
        good = (
            np.isfinite(root_r)
            & np.isfinite(root_h)
            & (max_rate(root_r, root_h, br, bh, p) < tol)
            & is_stable(j)
            & (mu < 0.0)
            & (2.0 * lip * dist < -mu)
        )
    ok = np.zeros(z_r.shape, dtype=bool)
    ok[near[good]] = True
    full_r = np.zeros(z_r.shape)
    full_h = np.zeros(z_r.shape)
    full_r[near] = root_r
    full_h[near] = root_h
    return ok, full_r, full_h


def _screen_bound(p: PairParams, lip: float) -> float:
    """An upper bound of max(|ż_r|, |ż_h|) at any state that `_certified` can accept.

    A certified state is within −μ₂/(2L) ≤ max(d_i + u_i|α_i|)/(2L) of z* (μ₂(J) is at least
    either diagonal entry of J), and |ż| ≤ ‖J‖ · distance along the segment, with ‖J‖ bounded by the
    Frobenius norm of the entries' largest magnitudes.
    """
    if lip == 0.0:  # J is constant: the field is affine and a stable equilibrium is global
        return math.inf
    r, h = p.robot, p.human
    j_max = math.sqrt(
        (r.d + r.u * abs(r.alpha)) ** 2
        + (r.u * r.gamma * p.a_rh) ** 2
        + (h.u * h.gamma * p.a_hr) ** 2
        + (h.d + h.u * abs(h.alpha)) ** 2
    )
    return j_max * max(r.d + r.u * abs(r.alpha), h.d + h.u * abs(h.alpha)) / (2.0 * lip)


def _result(
    b_r: np.ndarray,
    b_h: np.ndarray,
    z_r: np.ndarray,
    z_h: np.ndarray,
    conv: np.ndarray,
    z0: tuple[float, float],
    method: str,
    dt: float,
    horizon: float,
    tol: float,
    shape: tuple[int, int] | None = None,
) -> SweepResult:
    shape = shape or (np.size(b_h), np.size(b_r))
    return SweepResult(
        b_r=np.asarray(b_r, dtype=float),
        b_h=np.asarray(b_h, dtype=float),
        z_r=np.asarray(z_r).reshape(shape),
        z_h=np.asarray(z_h).reshape(shape),
        converged=np.asarray(conv).reshape(shape),
        z0=(float(z0[0]), float(z0[1])),
        method=method,
        dt=float(dt),
        horizon=float(horizon),
        tol=float(tol),
    )


def save_npz(result: SweepResult, path: str | Path, p: PairParams) -> None:
    """Write the sweep as .npz: the arrays plus its settings (`params` is a JSON string)."""
    np.savez(
        path,
        b_r=result.b_r,
        b_h=result.b_h,
        consensus=result.consensus,
        z_r=result.z_r,
        z_h=result.z_h,
        converged=result.converged,
        z0=np.array(result.z0),
        method=np.array(result.method),
        dt=np.array(result.dt),
        horizon=np.array(result.horizon),
        tol=np.array(result.tol),
        params=np.array(json.dumps(asdict(p))),
    )
