"""Every equilibrium of eqs 1-2 for given biases, with its stability (Fig 3b, eqs 3-5).

An equilibrium is a common zero of the nullcline functions (eqs 4-5, generalised to a
heterogeneous pair)

    Δ1(z_r, z_h) = tanh(α_r z_r + γ_r a_rh z_h) − (d_r z_r − b_r) / u_r
    Δ2(z_r, z_h) = tanh(α_h z_h + γ_h a_hr z_r) − (d_h z_h − b_h) / u_h,

i.e. of (ż_r, ż_h) = (u_r Δ1, u_h Δ2). Since |tanh| < 1, all lie in the box
|z_r| ≤ (u_r + |b_r|)/d_r, |z_h| ≤ (u_h + |b_h|)/d_h.

Method (no equilibrium missed, none duplicated). When d_r > u_r max(α_r, 0), the robot's
equation d_r z_r − u_r tanh(α_r z_r + γ_r a_rh z_h) = b_r is strictly increasing in z_r, so
it has exactly one solution z_r = φ(z_h) for each z_h, and the equilibria are in one-to-one
correspondence with the zeros of the continuous 1-D function H(z_h) = ż_h(φ(z_h), z_h) on the
box's z_h interval. Zeros are bracketed by sign changes on a fine grid; a discrete extremum of
H without a sign change is refined, so a pair of roots closer than the grid step (or a tangency
at a saddle-node) is caught too. Each bracket is bisected and the point polished by 2-D Newton.
If only the human's equation is monotone the roles are exchanged; if neither is, a dense grid
of Newton starts over the box with de-duplication is used (best effort, documented as such).

Stability from the eigenvalues of the Jacobian (eq 3): "stable" (both Re λ < 0), "unstable"
(both > 0), "saddle" (real, opposite signs), or "non-hyperbolic" (some Re λ = 0 to round-off,
as at a bifurcation). Eigenvalues are reported as [re, im] pairs, sorted by real part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, TypeAlias

import numpy as np

from services.analysis.fields import newton
from services.model.dynamics import PairParams, jacobian, pair_rhs

Stability: TypeAlias = Literal["stable", "unstable", "saddle", "non-hyperbolic"]

GRID = 4001  # samples of H over the z_h interval
_GOLD = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class Equilibrium:
    """One equilibrium (z_r, z_h) of eqs 1-2 and the Jacobian's eigenvalues there (eq 3)."""

    z_r: float
    z_h: float
    stability: Stability
    eigenvalues: tuple[complex, complex]  # sorted by real part

    @property
    def consensus(self) -> bool:
        """Whether sgn z_r = sgn z_h (Sec 4.1)."""
        return bool(np.sign(self.z_r) == np.sign(self.z_h))

    def as_dict(self) -> dict[str, object]:
        """JSON-ready form; each eigenvalue is a [re, im] pair."""
        return {
            "z_r": self.z_r,
            "z_h": self.z_h,
            "stability": self.stability,
            "consensus": self.consensus,
            "eigenvalues": [[v.real, v.imag] for v in self.eigenvalues],
        }


def deltas(
    z_r: np.ndarray | float, z_h: np.ndarray | float, b_r: float, b_h: float, p: PairParams
) -> tuple[np.ndarray, np.ndarray]:
    """(Δ1, Δ2) of eqs 4-5 (requires u_r, u_h > 0)."""
    if p.robot.u <= 0 or p.human.u <= 0:
        raise ValueError("Δ1, Δ2 (eqs 4-5) divide by u: both agents need u > 0")
    f_r, f_h = pair_rhs(np.asarray(z_r, float), np.asarray(z_h, float), b_r, b_h, p)
    return f_r / p.robot.u, f_h / p.human.u


def box(b_r: float, b_h: float, p: PairParams) -> tuple[float, float]:
    """Half-widths (Z_r, Z_h) of the box that holds every equilibrium."""
    return (p.robot.u + abs(b_r)) / p.robot.d, (p.human.u + abs(b_h)) / p.human.d


def classify(eigenvalues: tuple[complex, complex]) -> Stability:
    """Stability label from the two eigenvalues of the Jacobian."""
    re = [v.real for v in eigenvalues]
    tol = 1e-9 * max(1.0, *(abs(v) for v in eigenvalues))
    if min(abs(x) for x in re) <= tol:
        return "non-hyperbolic"
    if max(re) < 0:
        return "stable"
    if min(re) > 0:
        return "unstable"
    return "saddle"


def find_equilibria(
    b_r: float, b_h: float, p: PairParams | None = None, *, grid: int = GRID
) -> list[Equilibrium]:
    """Every equilibrium of eqs 1-2 at biases (b_r, b_h), sorted by (z_r, z_h)."""
    p = p or PairParams()
    b_r, b_h = float(b_r), float(b_h)
    if not (math.isfinite(b_r) and math.isfinite(b_h)):
        raise ValueError(f"biases must be finite, got b_r={b_r!r}, b_h={b_h!r}")
    if p.robot.d > p.robot.u * max(p.robot.alpha, 0.0):
        points = _by_reduction(b_r, b_h, p, grid)
    elif p.human.d > p.human.u * max(p.human.alpha, 0.0):
        swapped = PairParams(robot=p.human, human=p.robot, a_rh=p.a_hr, a_hr=p.a_rh)
        points = [(zr, zh) for zh, zr in _by_reduction(b_h, b_r, swapped, grid)]
    else:
        points = _by_multistart(b_r, b_h, p)
    return [_describe(zr, zh, p) for zr, zh in _dedupe(points)]


def _phi(z_h: np.ndarray, b_r: float, p: PairParams) -> np.ndarray:
    """z_r = φ(z_h): the unique root of d_r z_r − u_r tanh(α_r z_r + γ_r a_rh z_h) − b_r.

    Safeguarded Newton (bisection whenever a step leaves the bracket), vectorised over z_h.
    """
    r = p.robot
    c = r.gamma * p.a_rh
    big = (r.u + abs(b_r)) / r.d + 1.0
    lo = np.full(z_h.shape, -big)
    hi = np.full(z_h.shape, big)
    x = np.clip(b_r / r.d + np.zeros(z_h.shape), lo, hi)
    for _ in range(200):
        t = np.tanh(r.alpha * x + c * z_h)
        g = r.d * x - r.u * t - b_r
        lo = np.where(g < 0, x, lo)
        hi = np.where(g > 0, x, hi)
        step = g / (r.d - r.u * r.alpha * (1.0 - t * t))
        new = x - step
        out = (new <= lo) | (new >= hi)
        new = np.where(out, 0.5 * (lo + hi), new)
        moved = np.abs(new - x)
        x = np.where(g == 0, x, new)
        if np.all((moved <= 4e-16 * (1.0 + np.abs(x))) | (g == 0)):
            break
    return x


def _h(z_h: np.ndarray, b_r: float, b_h: float, p: PairParams) -> np.ndarray:
    """H(z_h) = ż_h at (φ(z_h), z_h): zero exactly at the equilibria."""
    z_r = _phi(z_h, b_r, p)
    return pair_rhs(z_r, z_h, b_r, b_h, p)[1]


def _by_reduction(b_r: float, b_h: float, p: PairParams, grid: int) -> list[tuple[float, float]]:
    """Equilibria through the 1-D reduction z_r = φ(z_h) (needs d_r > u_r max(α_r, 0))."""
    half = box(b_r, b_h, p)[1] * (1.0 + 1e-9) + 1e-12
    zs = np.linspace(-half, half, max(int(grid), 3))
    hs = _h(zs, b_r, b_h, p)
    roots: list[float] = list(zs[hs == 0.0])
    brackets: list[tuple[float, float]] = []
    sign = np.sign(hs)
    cells = np.flatnonzero(sign[:-1] * sign[1:] < 0)
    brackets += [(zs[k], zs[k + 1]) for k in cells]
    # Discrete extrema of H with one sign over three samples may hide two close roots.
    dh = np.diff(hs)
    for k in np.flatnonzero(dh[:-1] * dh[1:] < 0) + 1:
        s = sign[k]
        if s == 0 or sign[k - 1] != s or sign[k + 1] != s:
            continue
        a, b = zs[k - 1], zs[k + 1]
        x_e = _extremum(a, b, b_r, b_h, p, maximise=bool(s < 0))
        h_e = float(_h(np.array([x_e]), b_r, b_h, p)[0])
        scale = 1e-12 * (1.0 + abs(b_h) + p.human.u + p.human.d * half)
        if abs(h_e) <= scale:
            roots.append(x_e)  # tangency (saddle-node)
        elif np.sign(h_e) != s:
            brackets += [(a, x_e), (x_e, b)]
    if brackets:
        roots += list(_bisect(np.array(brackets), b_r, b_h, p))
    zh = np.array(roots, dtype=float)
    zr = _phi(zh, b_r, p)
    pr, ph = newton(zr, zh, b_r, b_h, p, iterations=6)
    out = []
    for i in range(zh.size):
        # Keep the Newton polish only if it improved the residual (it can wander near a
        # tangency, where the Jacobian is singular).
        before = _residual(zr[i], zh[i], b_r, b_h, p)
        after = _residual(pr[i], ph[i], b_r, b_h, p) if np.isfinite(pr[i] + ph[i]) else math.inf
        out.append((float(pr[i]), float(ph[i])) if after <= before else (zr[i], zh[i]))
    return out


def _bisect(brackets: np.ndarray, b_r: float, b_h: float, p: PairParams) -> np.ndarray:
    """Vectorised bisection of H over brackets [a, b] with a sign change."""
    a, b = brackets[:, 0].copy(), brackets[:, 1].copy()
    ha = _h(a, b_r, b_h, p)
    for _ in range(80):
        m = 0.5 * (a + b)
        hm = _h(m, b_r, b_h, p)
        left = np.sign(hm) == np.sign(ha)
        a = np.where(left, m, a)
        ha = np.where(left, hm, ha)
        b = np.where(left, b, m)
        if np.all(b - a <= 2e-16 * (1.0 + np.abs(a))):
            break
    return 0.5 * (a + b)


def _extremum(a: float, b: float, b_r: float, b_h: float, p: PairParams, maximise: bool) -> float:
    """Golden-section search for the extremum of H on [a, b]."""
    sgn = -1.0 if maximise else 1.0

    def f(x: float) -> float:
        return sgn * float(_h(np.array([x]), b_r, b_h, p)[0])

    c, d = b - _GOLD * (b - a), a + _GOLD * (b - a)
    fc, fd = f(c), f(d)
    for _ in range(80):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - _GOLD * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + _GOLD * (b - a)
            fd = f(d)
    return 0.5 * (a + b)


def _by_multistart(
    b_r: float, b_h: float, p: PairParams, n: int = 161
) -> list[tuple[float, float]]:
    """Best effort for non-monotone agents: Newton from every point of a grid over the box."""
    zr_half, zh_half = box(b_r, b_h, p)
    ZR, ZH = np.meshgrid(np.linspace(-zr_half, zr_half, n), np.linspace(-zh_half, zh_half, n))
    zr, zh = newton(ZR.ravel(), ZH.ravel(), b_r, b_h, p, iterations=60)
    out = []
    for x, y in zip(zr, zh, strict=True):
        if np.isfinite(x) and np.isfinite(y) and _residual(x, y, b_r, b_h, p) < 1e-12:
            out.append((float(x), float(y)))
    return out


def _residual(z_r: float, z_h: float, b_r: float, b_h: float, p: PairParams) -> float:
    """max(|Δ1|, |Δ2|), or max(|ż_r|, |ż_h|) for an agent with u = 0."""
    f_r, f_h = pair_rhs(np.float64(z_r), np.float64(z_h), b_r, b_h, p)
    u_r = p.robot.u if p.robot.u > 0 else 1.0
    u_h = p.human.u if p.human.u > 0 else 1.0
    return float(max(abs(f_r) / u_r, abs(f_h) / u_h))


def _dedupe(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Sort by (z_r, z_h) and merge points closer than 1e-8 (same equilibrium twice)."""
    kept: list[tuple[float, float]] = []
    for zr, zh in sorted(points):
        if kept and any(math.hypot(zr - a, zh - b) < 1e-8 for a, b in kept):
            continue
        kept.append((zr, zh))
    return kept


def _describe(z_r: float, z_h: float, p: PairParams) -> Equilibrium:
    vals = sorted(np.linalg.eigvals(jacobian(z_r, z_h, p)), key=lambda v: (v.real, v.imag))
    eig = (complex(vals[0]), complex(vals[1]))
    return Equilibrium(z_r=float(z_r), z_h=float(z_h), stability=classify(eig), eigenvalues=eig)
