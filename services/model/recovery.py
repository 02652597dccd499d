"""Parameter recovery: how well a fit gives back parameters that were planted (pure numbers).

A recovery study (Wilson & Collins 2019, "Ten simple rules for the computational modeling of
behavioral data") simulates people with known parameters, fits them as real people are fitted,
and compares. Per parameter: the correlation of true and estimated values, the mean bias
(estimated − true), and the coverage (share of true values inside their interval). A parameter
is `identifiable` when the correlation is at least `MIN_CORRELATION` and the coverage of the
90 % interval lies within `COVERAGE`: otherwise its estimates are not findings. A parameter
spread log-normally is correlated on its log (`Recovery.scale`). Coverage above
the range means intervals too wide to say much — unless they are single values (a 0/1
parameter's set {0} or {1}) for most people: then the truth is named, and rightly.

A verdict is only as sure as the r and the coverage it reads, and a recovery of 60 people
leaves both uncertain: `recovery_intervals` gives a percentile-bootstrap interval of r (people
resampled, from a fixed seed: the same numbers on a rerun) and the Wilson score interval of the
coverage, and says when the verdict is at the edge (either interval reaches across its
threshold, so another draw of people could turn it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist
from typing import Any

import numpy as np

MIN_CORRELATION = 0.7
COVERAGE = (0.80, 0.98)
CI_LEVEL = 0.95  # the level of the intervals of r and of the coverage
BOOTSTRAP_DRAWS = 2000  # resamples of the people: the interval's ends to about ±0.01 in r


@dataclass(frozen=True, slots=True)
class Recovery:
    """One parameter's recovery."""

    name: str
    correlation: float  # Pearson, true vs estimated (NaN: a constant on either side)
    bias: float  # mean of estimated − true
    coverage: float  # share of true values within [low, high]
    n: int
    exact: float = 0.0  # share of intervals that are one value (low == high)
    # "log": r is of the logs. A trait spread log-normally over a decade (gaze_gain) is learnt
    # on its log, where people are spread evenly; Pearson's r of the raw values is set by the
    # few people at the top of the decade (it swung 0.58-0.74 between two recoveries of one
    # cohort). Coverage and bias do not depend on it (bias is in the parameter's own units).
    scale: str = "linear"

    @property
    def identifiable(self) -> bool:
        """Recovered to the standard: correlation ≥ 0.7 and coverage within 0.80-0.98."""
        return (
            math.isfinite(self.correlation)
            and self.correlation >= MIN_CORRELATION
            and COVERAGE[0] <= self.coverage
            and (self.coverage <= COVERAGE[1] or self.exact >= 0.5)
        )

    def as_dict(self) -> dict[str, float | bool | str | int | None]:
        """The JSON form `nod fit recovery --json` prints."""
        return {"name": self.name, "correlation": _num(self.correlation),
                "bias": _num(self.bias), "coverage": _num(self.coverage),
                "identifiable": self.identifiable, "n": self.n, "exact": _num(self.exact),
                "scale": self.scale}


def _num(x: float) -> float | None:
    """A number for JSON: rounded; None (null) for NaN, which JSON cannot hold."""
    return round(x, 4) if math.isfinite(x) else None


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson's r; NaN when either side does not vary.

    Each side's deviations are scaled to a largest of 1 first: `np.corrcoef` squares them, and
    values that differ by 1e-190 (hypothesis found them) underflowed to 0/0.
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.size < 2:
        return math.nan
    da, db = a - a.mean(), b - b.mean()
    sa, sb = float(np.max(np.abs(da))), float(np.max(np.abs(db)))
    if sa == 0 or sb == 0:
        return math.nan
    da, db = da / sa, db / sb
    r = float(np.sum(da * db) / math.sqrt(float(np.sum(da * da)) * float(np.sum(db * db))))
    return max(-1.0, min(1.0, r))


def recovery(name: str, true: np.ndarray, estimate: np.ndarray, low: np.ndarray,
             high: np.ndarray, log: bool = False) -> Recovery:
    """Compare planted values with their estimates and intervals (`log`: r of the logs)."""
    true, estimate = np.asarray(true, float), np.asarray(estimate, float)
    low, high = np.asarray(low, float), np.asarray(high, float)
    inside = (low <= true) & (true <= high)
    if log and (true > 0).all() and (estimate > 0).all():
        r, scale = correlation(np.log(true), np.log(estimate)), "log"
    else:
        r, scale = correlation(true, estimate), "linear"
    return Recovery(name, r, float(np.mean(estimate - true)), float(np.mean(inside)),
                    int(true.size), float(np.mean(low == high)), scale)


def wilson(successes: int, n: int, level: float = CI_LEVEL) -> tuple[float, float]:
    """The Wilson score interval of a proportion (NaN, NaN for n = 0).

    Not the normal (Wald) interval: a coverage of 0.98 or 1.00 on 60 people is where the
    verdict is read, and there Wald's interval is too narrow or leaves [0, 1].
    """
    if n <= 0:
        return math.nan, math.nan
    z = NormalDist().inv_cdf(0.5 + level / 2)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def bootstrap_correlation(a: np.ndarray, b: np.ndarray, seed: int,
                          draws: int = BOOTSTRAP_DRAWS, level: float = CI_LEVEL
                          ) -> tuple[float, float]:
    """The percentile-bootstrap interval of Pearson's r: people resampled with replacement.

    The rng is seeded, so a rerun gives the same interval. A resample in which either side
    does not vary has no r and is left out; none left: (NaN, NaN). Resampled in chunks, so a
    recovery of many people never holds draws × people numbers at once.
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = a.size
    if n < 2:
        return math.nan, math.nan
    # Scaled as `correlation` scales them, so tiny deviations do not underflow when squared.
    a, b = a - a.mean(), b - b.mean()
    a, b = a / (float(np.max(np.abs(a))) or 1.0), b / (float(np.max(np.abs(b))) or 1.0)
    rng = np.random.default_rng(seed)
    rs = []
    chunk = max(1, 2_000_000 // n)
    for start in range(0, draws, chunk):
        idx = rng.integers(0, n, (min(chunk, draws - start), n))
        x, y = a[idx], b[idx]
        x = x - x.mean(axis=1, keepdims=True)
        y = y - y.mean(axis=1, keepdims=True)
        den = np.sqrt(np.sum(x * x, axis=1) * np.sum(y * y, axis=1))
        with np.errstate(invalid="ignore", divide="ignore"):
            r = np.sum(x * y, axis=1) / den
        rs.append(r[den > 0])
    every = np.clip(np.concatenate(rs), -1.0, 1.0)
    if every.size == 0:
        return math.nan, math.nan
    lo, hi = np.quantile(every, [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)


def recovery_intervals(rec: Recovery, true: np.ndarray, estimate: np.ndarray,
                       low: np.ndarray, high: np.ndarray, seed: int) -> dict[str, Any]:
    """The 95 % intervals of a recovery's r (bootstrap) and coverage (Wilson), for its JSON.

    `edge`: the verdict could turn within them — r's interval reaches across 0.7, or the
    coverage's across 0.80 or (unless most sets are one value) 0.98.
    """
    true, estimate = np.asarray(true, float), np.asarray(estimate, float)
    a, b = (np.log(true), np.log(estimate)) if rec.scale == "log" else (true, estimate)
    r_ci = bootstrap_correlation(a, b, seed)
    inside = int(np.sum((np.asarray(low, float) <= true) & (true <= np.asarray(high, float))))
    c_ci = wilson(inside, rec.n)
    edge = bool(
        (r_ci[0] < MIN_CORRELATION <= r_ci[1])
        or (c_ci[0] < COVERAGE[0] <= c_ci[1])
        or (rec.exact < 0.5 and c_ci[0] <= COVERAGE[1] < c_ci[1])
    )
    return {"correlation_ci95": [_num(v) for v in r_ci],
            "coverage_ci95": [_num(v) for v in c_ci], "edge": edge}
