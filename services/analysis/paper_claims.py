"""Three claims of the paper that the code can settle, each computed rather than argued.

1. **68.125** (Sec 7.1, the Stuart–Maxwell statistic of control vs experiment): every paired
   table with the published phase margins (control C 16 / D 35; experiment C 32 / CH 12 / D 7)
   is enumerated and tested; the range of statistics they can give decides whether any table
   could have produced the published number.
2. **The unique-equilibrium bias** (Sec 4.4.1 claims consensus once |b| > u): on the diagonal
   b_r = b_h = b, the bias above which eqs 1-2 have a single equilibrium, found by bisection on
   the equilibrium count, against u.
3. **Fig 3a and its initial condition**: the bias sweep integrates from a starting opinion the
   paper does not state; the consensus map is recomputed from several starts and compared.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from services.analysis.equilibria import find_equilibria
from services.analysis.stuart_maxwell import stuart_maxwell
from services.analysis.sweep import DEFAULT_Z0, bias_grid, consensus_map, sweep
from services.model.dynamics import PairParams

# Sec 7.1's phase margins in the order C, CH, D, DH: 16 participants were C and 35 D in the
# control phase; the experiment phase had C 32, CH 12, D 7 (docs/study.md, "Paper check").
PAPER_CONTROL_MARGINS = (16, 0, 35, 0)
PAPER_EXPERIMENT_MARGINS = (32, 12, 7, 0)
PAPER_STATISTIC = 68.125

# Starting opinions for Fig 3a: the sweep's default (origin with a 1e-6 robot lean), the mirror
# leans, and opinions already committed in agreement or disagreement.
FIG3A_STARTS: tuple[tuple[float, float], ...] = (
    DEFAULT_Z0,
    (0.0, 1e-6),
    (-1e-6, 0.0),
    (1.0, 1.0),
    (-1.0, -1.0),
    (1.0, -1.0),
    (-1.0, 1.0),
)


def tables_with_margins(
    rows: Sequence[int], cols: Sequence[int], limit: int = 2_000_000
) -> Iterator[np.ndarray]:
    """Every k×k non-negative integer table with these row and column totals.

    Raises ValueError when the totals differ or the count would pass `limit` (a guard against
    enumerations that cannot finish).
    """
    k = len(rows)
    if len(cols) != k or sum(rows) != sum(cols) or min(*rows, *cols) < 0:
        raise ValueError(f"margins must be non-negative with equal totals: {rows} vs {cols}")
    table = np.zeros((k, k), dtype=int)
    count = 0

    def fill(i: int, j: int, left: list[int]) -> Iterator[np.ndarray]:
        nonlocal count
        if i == k:
            count += 1
            if count > limit:
                raise ValueError(f"more than {limit} tables: too many to enumerate")
            yield table.copy()
            return
        row_left = rows[i] - int(table[i, :j].sum())
        if j == k - 1:  # the last cell of a row is forced
            if row_left <= left[j]:
                table[i, j] = row_left
                left[j] -= row_left
                yield from fill(i + 1, 0, left)
                left[j] += row_left
            return
        for v in range(min(row_left, left[j]) + 1):
            table[i, j] = v
            left[j] -= v
            yield from fill(i, j + 1, left)
            left[j] += v
        table[i, j] = 0

    yield from fill(0, 0, list(cols))


@dataclass(frozen=True)
class MarginSearch:
    """What the tables with given margins can give as a Stuart–Maxwell statistic."""

    tables: int  # how many tables have the margins
    testable: int  # of which the test is defined (S invertible)
    minimum: float
    maximum: float
    target: float
    closest: float  # the statistic nearest the target
    closest_table: list[list[int]]

    @property
    def attainable(self) -> bool:
        """Whether some table gives the target to the printed precision (3 decimals)."""
        return abs(self.closest - self.target) < 5e-4

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {
            "tables": self.tables, "testable": self.testable, "minimum": self.minimum,
            "maximum": self.maximum, "target": self.target, "closest": self.closest,
            "closest_table": self.closest_table, "attainable": self.attainable,
        }


def statistic_over_margins(
    rows: Sequence[int] = PAPER_CONTROL_MARGINS,
    cols: Sequence[int] = PAPER_EXPERIMENT_MARGINS,
    target: float = PAPER_STATISTIC,
) -> MarginSearch:
    """Stuart–Maxwell over every table with the margins; the range and the nearest to target."""
    stats: list[tuple[float, np.ndarray]] = []
    total = 0
    for table in tables_with_margins(rows, cols):
        total += 1
        try:
            stats.append((stuart_maxwell(table).statistic, table))
        except ValueError:
            continue  # singular S (e.g. no discordant pairs): the test is undefined
    if not stats:
        raise ValueError("no table with these margins can be tested")
    values = [s for s, _ in stats]
    near, near_table = min(stats, key=lambda st: abs(st[0] - target))
    return MarginSearch(
        total, len(stats), min(values), max(values), target, near, near_table.tolist()
    )


@dataclass(frozen=True)
class UniqueBias:
    """Where the diagonal b_r = b_h = b leaves the multistable region."""

    b_unique: float  # above this, one equilibrium
    b_all_consensus: float  # above this, every equilibrium is a consensus (sgn z_r = sgn z_h)
    u: float  # the paper's threshold u_r
    count_at_u: int  # equilibria at b = u (the claim says one, in consensus)
    consensus_at_u: bool  # every equilibrium at b = u is a consensus
    count_below: int  # equilibria just below b_unique

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {
            "b_unique": self.b_unique, "b_all_consensus": self.b_all_consensus, "u": self.u,
            "count_at_u": self.count_at_u, "consensus_at_u": self.consensus_at_u,
            "count_below": self.count_below,
        }


def _threshold(test, lo: float, hi: float, tol: float) -> tuple[float, float]:
    """Bisection for the b where `test(b)` turns true (false at lo, true at hi)."""
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if test(mid):
            hi = mid
        else:
            lo = mid
    return lo, hi


def unique_equilibrium_bias(p: PairParams | None = None, tol: float = 1e-7) -> UniqueBias:
    """Bisection on b for the smallest diagonal bias with a single equilibrium.

    The count is 3 at b = 0 (two stable dissensus states and a saddle when u > u_d*) and 1 for
    a large bias; between, it drops once, at a saddle-node where a stable state and the saddle
    meet. The same bisection finds where every equilibrium becomes a consensus.
    """
    p = p or PairParams()
    hi = max(1.0, 4.0 * (p.robot.u + p.human.u))

    def unique(b: float) -> bool:
        return len(find_equilibria(b, b, p)) == 1

    def all_consensus(b: float) -> bool:
        return all(e.consensus for e in find_equilibria(b, b, p))

    if unique(0.0):
        raise ValueError("a single equilibrium already at b = 0: nothing to find")
    if not (unique(hi) and all_consensus(hi)):
        raise ValueError(f"still several equilibria, or a dissensus, at b = {hi:g}")
    lo, hi_unique = _threshold(unique, 0.0, hi, tol)
    _, hi_consensus = _threshold(all_consensus, 0.0, hi, tol)
    at_u = find_equilibria(p.robot.u, p.robot.u, p)
    return UniqueBias(
        b_unique=hi_unique,
        b_all_consensus=hi_consensus,
        u=p.robot.u,
        count_at_u=len(at_u),
        consensus_at_u=all(e.consensus for e in at_u),
        count_below=len(find_equilibria(lo, lo, p)),
    )


@dataclass(frozen=True)
class StartDependence:
    """Fig 3a from one starting opinion, against the default start."""

    z0: tuple[float, float]
    consensus_share: float  # share of the grid in consensus
    differs_from_default: float  # share of the grid classified otherwise than from DEFAULT_Z0

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {
            "z0": list(self.z0), "consensus_share": self.consensus_share,
            "differs_from_default": self.differs_from_default,
        }


def fig3a_start_dependence(
    p: PairParams | None = None,
    grid: int = 61,
    half_range: float = 6.0,
    starts: Sequence[tuple[float, float]] = FIG3A_STARTS,
) -> list[StartDependence]:
    """The Fig 3a consensus map from each start, and how much of it changes."""
    p = p or PairParams()
    b = bias_grid(grid, half_range)
    maps = []
    for z0 in starts:
        r = sweep(b, b, p, z0=z0)
        maps.append(consensus_map(r.z_r, r.z_h))
    base = maps[starts.index(DEFAULT_Z0)] if DEFAULT_Z0 in starts else maps[0]
    return [
        StartDependence(
            (float(z0[0]), float(z0[1])), float(m.mean()), float((m != base).mean())
        )
        for z0, m in zip(starts, maps, strict=True)
    ]


def report(p: PairParams | None = None, grid: int = 61) -> dict[str, Any]:
    """All three, JSON-ready."""
    p = p or PairParams()
    return {
        "stuart_maxwell_over_margins": statistic_over_margins().as_dict(),
        "unique_equilibrium_bias": unique_equilibrium_bias(p).as_dict(),
        "fig3a_initial_condition": [s.as_dict() for s in fig3a_start_dependence(p, grid)],
    }


def format_report(doc: dict[str, Any]) -> str:
    """The report for a terminal."""
    sm = doc["stuart_maxwell_over_margins"]
    ub = doc["unique_equilibrium_bias"]
    lines = [
        "1. Stuart–Maxwell 68.125 from the published margins (control C 16 / D 35; "
        "experiment C 32 / CH 12 / D 7)?",
        f"   {sm['tables']} tables have those margins ({sm['testable']} testable): X² from "
        f"{sm['minimum']:.3f} to {sm['maximum']:.3f}; nearest to {sm['target']:g} is "
        f"{sm['closest']:.3f} -> {'attainable' if sm['attainable'] else 'NOT attainable'}",
        "2. Unique equilibrium on the diagonal b_r = b_h = b:",
        f"   every equilibrium a consensus for b > {ub['b_all_consensus']:.6f}; "
        f"one equilibrium for b > {ub['b_unique']:.6f} ({ub['count_below']} below); the paper's "
        f"threshold u = {ub['u']:g} gives {ub['count_at_u']} equilibria"
        + (" (all consensus)" if ub["consensus_at_u"] else " (not all consensus)"),
        "3. Fig 3a from different starting opinions (share in consensus; share that differs "
        "from the default start):",
    ]
    for s in doc["fig3a_initial_condition"]:
        z0 = f"({s['z0'][0]:g}, {s['z0'][1]:g})"
        lines.append(
            f"   z0 = {z0:<12} consensus {100 * s['consensus_share']:5.1f} %   "
            f"differs {100 * s['differs_from_default']:5.1f} %"
        )
    return "\n".join(lines)
