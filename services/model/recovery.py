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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MIN_CORRELATION = 0.7
COVERAGE = (0.80, 0.98)


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
