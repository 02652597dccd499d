"""Stuart-Maxwell test of marginal homogeneity for a k×k paired table (Secs 7-8, SPEC §7).

For a table n (rows: first classification, e.g. control; columns: second, e.g. experiment)
with row margins n_i. and column margins n_.i, over k − 1 of the k categories:

    d_i  = n_i. − n_.i
    S_ii = n_i. + n_.i − 2 n_ii,      S_ij = −(n_ij + n_ji)   (i ≠ j)
    X²   = dᵀ S⁻¹ d  ~  χ²(k − 1)  under marginal homogeneity.

Categories empty in both margins (row i and column i all zero) carry no information and are
dropped first (SPEC §7); the statistic does not depend on which remaining category is left out
(the last one is). For k = 2 it is McNemar's (b − c)² / (b + c).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StuartMaxwellResult:
    """The test's outcome."""

    statistic: float  # X² = dᵀ S⁻¹ d
    df: int  # k − 1 over the categories kept
    p: float  # upper tail of χ²(df) at the statistic
    kept: tuple[int, ...]  # indices (in the input table) of the categories used

    def as_dict(self) -> dict[str, object]:
        """JSON-ready form."""
        return {"statistic": self.statistic, "df": self.df, "p": self.p, "kept": list(self.kept)}


def as_table(table: Sequence[Sequence[float]] | np.ndarray) -> np.ndarray:
    """Validate a square table of non-negative finite counts and return it as floats."""
    if isinstance(table, np.ndarray):
        arr = table
    else:
        if not isinstance(table, Sequence) or isinstance(table, str | bytes):
            raise ValueError("table must be a list of rows")
        rows = list(table)
        if not rows or not all(
            isinstance(r, Sequence) and not isinstance(r, str | bytes) for r in rows
        ):
            raise ValueError("table must be a non-empty list of rows (lists of counts)")
        widths = {len(r) for r in rows}
        if len(widths) != 1:
            raise ValueError(f"table is ragged: row lengths {sorted(widths)}")
        for r in rows:
            for v in r:
                if isinstance(v, bool) or not isinstance(v, int | float | np.number):
                    raise ValueError(f"table entries must be numbers, got {v!r}")
        arr = np.array(rows, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1]:
        raise ValueError(f"table must be square (k×k), got shape {arr.shape}")
    arr = arr.astype(float)
    if not np.all(np.isfinite(arr)):
        raise ValueError("table entries must be finite")
    if np.any(arr < 0):
        raise ValueError("table entries are counts and must be >= 0")
    return arr


def stuart_maxwell(
    table: Sequence[Sequence[float]] | np.ndarray, drop: int | None = None
) -> StuartMaxwellResult:
    """Stuart-Maxwell X², df and p for a paired k×k table (see the module docstring).

    `drop` chooses which kept category (index into the input table) is left out of d and S;
    by default the last kept one. Raises ValueError with the reason for a malformed table, for
    fewer than two non-empty categories, or when S is singular (e.g. no discordant pairs).
    """
    n = as_table(table)
    rows, cols = n.sum(axis=1), n.sum(axis=0)
    kept = tuple(int(i) for i in np.flatnonzero((rows > 0) | (cols > 0)))
    if len(kept) < 2:
        raise ValueError(
            f"need at least 2 categories with observations, found {len(kept)}: nothing to test"
        )
    if drop is None:
        drop = kept[-1]
    if drop not in kept:
        raise ValueError(f"cannot drop category {drop}: not among the non-empty ones {kept}")
    use = [i for i in kept if i != drop]
    sub = n[np.ix_(use, use)]
    d = rows[use] - cols[use]
    S = -(sub + sub.T)
    S[np.diag_indices_from(S)] = rows[use] + cols[use] - 2.0 * np.diag(sub)
    # S is positive semi-definite; it is singular when some category has no discordant pair
    # linking it to the rest (for example a perfectly concordant table).
    scale = max(float(np.abs(S).max()), 1.0)
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        L = None
    if L is None or float(np.min(np.abs(np.diag(L)))) ** 2 <= 1e-12 * scale:
        raise ValueError(
            "the Stuart-Maxwell covariance S is singular (too few discordant pairs, e.g. all "
            "counts on the diagonal): the test is undefined for this table"
        )
    from scipy.stats import chi2  # lazy: scipy.stats is slow to import

    y = np.linalg.solve(L, d)
    stat = float(y @ y)
    df = len(kept) - 1
    return StuartMaxwellResult(statistic=stat, df=df, p=float(chi2.sf(stat, df)), kept=kept)


def mcnemar(b: float, c: float) -> float:
    """McNemar's statistic (b − c)² / (b + c) for the off-diagonal counts of a 2×2 table."""
    if b + c <= 0 or not (math.isfinite(b) and math.isfinite(c)):
        raise ValueError("McNemar needs b + c > 0")
    return (b - c) ** 2 / (b + c)
