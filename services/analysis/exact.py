"""Honest small samples: when a test's approximation holds, and exact tests for when it does not.

Pure: numbers in, numbers out.

Each test of the study report comes with a p from an approximation: Stuart-Maxwell's X² is
χ²(df) only for many discordant pairs, a χ² goodness of fit only for expected counts ≥ 5, a
t-test only for roughly normal means (nothing can check that on fewer than 5 answers). Beside
each such p the report gives `approximation_ok` and, where it fails, a `caveat` naming the rule
and an exact p:

- **Stuart-Maxwell → exact conditional test of marginal homogeneity.** Under the null each
  discordant pair is as likely in cell (i, j) as in (j, i): given the pair sums m_ij = n_ij +
  n_ji, n_ij ~ Binomial(m_ij, 1/2), independently. S depends only on the m_ij, so X² = dᵀS⁻¹d
  is enumerated over every d these binomials give; p = P(X² ≥ observed). For a 2×2 table it
  is the exact (binomial) McNemar test. Rule for the χ²: at least `MIN_DISCORDANT_PER_DF` = 10
  discordant pairs per degree of freedom.
- **χ² goodness of fit → exact multinomial test**: p = the probability, under the null, of
  every table no more likely than the observed one. Rule: every expected count ≥ 5.
- **One-sample t → exact sign-flip test** (the ratings symmetric about the midpoint under the
  null; with the sum of squares fixed, |t| grows with |Σ(x − midpoint)|). Rule: n ≥ 5.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

MIN_DISCORDANT_PER_DF = 10
MIN_EXPECTED = 5.0
MIN_T_N = 5
MAX_EXACT_STATES = 200_000  # beyond, the sample is large enough for the χ² anyway
MAX_SIGN_FLIP_N = 16  # 2**16 sign patterns
_TIES = 1e-9  # relative: a statistic equal to the observed one counts as "as extreme"


def discordant(table: np.ndarray, kept: Sequence[int]) -> int:
    """The pairs off the diagonal among the categories `kept`."""
    sub = np.asarray(table, dtype=float)[np.ix_(kept, kept)]
    return int(round(float(sub.sum() - np.trace(sub))))


def marginal_homogeneity_exact(table: np.ndarray, kept: Sequence[int]) -> float | None:
    """The exact conditional p of the Stuart-Maxwell statistic (None: too large to enumerate).

    `kept`: the categories the test used (the last one left out of d, as `stuart_maxwell` does).
    """
    n = np.asarray(table, dtype=float)
    use = list(kept[:-1])
    sub = n[np.ix_(use, use)]
    rows, cols = n.sum(axis=1), n.sum(axis=0)
    S = -(sub + sub.T)
    S[np.diag_indices_from(S)] = rows[use] + cols[use] - 2.0 * np.diag(sub)
    S_inv = np.linalg.inv(S)
    d_obs = rows[use] - cols[use]
    observed = float(d_obs @ S_inv @ d_obs)
    where = {c: k for k, c in enumerate(use)}  # the left-out category has no coordinate in d
    states: dict[tuple[int, ...], float] = {(0,) * len(use): 1.0}
    for i, j in itertools.combinations(kept, 2):
        m = int(round(n[i, j] + n[j, i]))
        if m == 0:
            continue
        pmf = [math.comb(m, x) / 2.0**m for x in range(m + 1)]
        step = np.zeros(len(use), dtype=int)
        if i in where:
            step[where[i]] += 1
        if j in where:
            step[where[j]] -= 1
        new: dict[tuple[int, ...], float] = {}
        for d, p in states.items():
            for x, px in enumerate(pmf):
                key = tuple(int(v) for v in np.asarray(d) + (2 * x - m) * step)
                new[key] = new.get(key, 0.0) + p * px
        if len(new) > MAX_EXACT_STATES:
            return None
        states = new
    d_all = np.array(list(states), dtype=float)
    probs = np.array(list(states.values()))
    stats = np.einsum("ni,ij,nj->n", d_all, S_inv, d_all)
    return float(min(1.0, probs[stats >= observed - _TIES * max(1.0, observed)].sum()))


def stuart_maxwell_small(table: np.ndarray, kept: Sequence[int], df: int) -> dict[str, object]:
    """`approximation_ok`, and for a table too small for the χ²: the exact p and the caveat."""
    pairs = discordant(table, kept)
    ok = pairs >= MIN_DISCORDANT_PER_DF * df
    doc: dict[str, object] = {"discordant_pairs": pairs, "approximation_ok": ok}
    if ok:
        return doc
    exact = marginal_homogeneity_exact(table, kept)
    doc["p_exact"] = exact
    doc["caveat"] = (
        f"{pairs} discordant pair(s) for df {df}: too few for the χ² approximation (rule: ≥ "
        f"{MIN_DISCORDANT_PER_DF} per df); "
        + (f"exact conditional p = {exact:.3g}" if exact is not None else "no exact p")
    )
    return doc


def multinomial_exact(observed: Sequence[int]) -> float:
    """Exact multinomial goodness-of-fit p against equal probabilities.

    The probability of every table of the same n no more likely than the observed one.
    """
    n, k = sum(observed), len(observed)

    def log_pmf(counts: Sequence[int]) -> float:
        return (math.lgamma(n + 1) - sum(math.lgamma(c + 1) for c in counts) - n * math.log(k))

    cut = log_pmf(observed) + 1e-9
    total = 0.0
    for cuts in itertools.combinations(range(n + k - 1), k - 1):  # stars and bars
        counts = [b - a - 1 for a, b in zip((-1, *cuts), (*cuts, n + k - 1), strict=True)]
        lp = log_pmf(counts)
        if lp <= cut:
            total += math.exp(lp)
    return min(1.0, total)


def goodness_of_fit_small(observed: Sequence[int]) -> dict[str, object]:
    """`approximation_ok` of a χ² against equal probabilities; if not: the exact p, the caveat."""
    n, k = sum(observed), len(observed)
    expected = n / k
    ok = expected >= MIN_EXPECTED
    doc: dict[str, object] = {"approximation_ok": ok}
    if not ok:
        exact = multinomial_exact(observed)
        doc["p_exact"] = exact
        doc["caveat"] = (f"expected count {expected:.3g} < {MIN_EXPECTED:g}: the χ² approximation "
                         f"does not hold; exact multinomial p = {exact:.3g}")
    return doc


def sign_flip_exact(values: Sequence[float], centre: float) -> float | None:
    """Exact two-sided sign-flip p of the mean against `centre` (None: n > MAX_SIGN_FLIP_N)."""
    y = np.asarray(values, dtype=float) - centre
    if y.size > MAX_SIGN_FLIP_N:
        return None
    signs = 1 - 2 * ((np.arange(2**y.size)[:, None] >> np.arange(y.size)) & 1)
    sums = np.abs(signs @ y)
    observed = abs(float(y.sum()))
    return float((sums >= observed - _TIES * max(1.0, observed)).mean())


def t_test_small(values: Sequence[float], centre: float) -> dict[str, object]:
    """`approximation_ok` of a one-sample t-test; if n is too small: the exact p, the caveat."""
    n = len(values)
    ok = n >= MIN_T_N
    doc: dict[str, object] = {"approximation_ok": ok}
    if not ok:
        exact = sign_flip_exact(values, centre)
        doc["p_exact"] = exact
        doc["caveat"] = (f"only {n} answers: a t-test needs about {MIN_T_N} or more to be "
                         f"trusted; exact sign-flip p = {exact:.3g}")
    return doc
