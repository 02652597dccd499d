"""Is a person inside the prior? Three summary scores, each calibrated on the prior's own people.

The fit's intervals are calibrated over the prior: they say nothing of a person the prior
cannot produce. So each person's summaries are checked against the reference table before
their estimates are read. Every summary is read as its normal score among the reference's
values of it (its mid-rank, through the inverse normal: a press time of 12 s counts as far out
as the rank says, not as its seconds would), a missing summary (a timeout, a turn never made)
counted by its own 0/1 feature instead of a value. Three scores:

- **distance**: the mean distance to the person's `K_NEAREST` nearest table people (the
  reference: the rows the estimator learnt from) — no one in the prior looks like someone far
  from all of them. On the reference tables the normal scores caught more people of other
  populations than summaries scaled by their sd (split person: 0.36 against 0.31 flagged under
  the shipped prior; docs/fit.md);
- **inconsistency**: the largest, over the features, of a feature's standardised residual when
  it is predicted linearly from all the others (ridge `RIDGE` on the reference's correlations:
  the residual of feature j is (P z)_j / √P_jj with P the regularised inverse correlation) —
  a person each of whose summaries is common but who combines them as no one in the prior does
  (the split person's hand, fast in one trial and crawling in the next where the prior's
  person keeps one speed). It raised the split person's flag rate from 0.47 to 0.53 and 0.44
  to 0.52 on two seeds under the shipped prior, with the prior's own people's unchanged
  (docs/fit.md, Out of the prior). It needs correlations estimated on at least
  `PEOPLE_PER_FEATURE` reference people per feature that varies (570 for the 114 of the
  shipped tables: a table of about 800 people or more);
  on a smaller table the check is the distance's alone;
- **spread**: how unlike the reference's is the person's spread from trial to trial. The two
  scores above read each trial's summary as one more number; a person whose every trial is
  typical but whose trials differ from each other as no one's in the prior do (a hand that
  crawls in one trial and is fast in the next, where the prior's person keeps one speed) is
  unusual only in a quantity neither sees, since a spread is no linear function of the values.
  So per summary measured in every trial (`SPREAD_FAMILIES`: onset, hand speed, press time,
  travel, slow speed, each positive), the sd of its log over the person's trials (unit-free:
  a person's trial-to-trial variation relative to their own level; NaN below 2 trials), read
  as its normal score among the reference's with a 0/1 feature where it is missing, as the
  summaries are; the score is the squared Mahalanobis distance of those features from the
  reference's mean (ridge `RIDGE` on their correlations: the families' spreads go together,
  travel being press less onset). Derived inside the check from the summaries the estimator
  reads, so its tables are unchanged. On the split person it raised the flag rate from 0.53,
  0.515 and 0.465 to 0.68, 0.695 and 0.645 on three seeds under the shipped prior (each
  Wilson interval above a half), the prior's own people flagged 70 of 1600, 0.044
  (docs/fit.md, Out of the prior). The per-trial columns are the caller's
  (`spread_columns`: `summary_columns()` for the summary vector); with none, or fewer than
  `PEOPLE_PER_FEATURE` reference people per spread feature that varies, the score is 0 for
  everyone and the check is the other two's. It is scored only where the inconsistency is: on
  a smaller table the check stays the distance's alone, because its calibration is small too
  (a table of 100 people holds out 30) and each score added takes from it: with three, a
  person strangest of the bag in one score but not in another has p ≥ 2/31 > ALPHA (tied with
  the held-out person strangest in that one), so only the strangest in all three is flagged.

**The calibration** is split-conformal novelty detection (Bates, Candès, Lei, Romano & Sesia
2023, "Testing for outliers with conformal p-values"), on the held-out table people (people of
the prior the reference does not hold). Each score's p-value is the person's rank among the
held-out people's, (1 + #{held-out scores ≥ theirs}) / (n + 1); the three are combined by
ranking again: in the bag of the n held-out people and the person, everyone's p-value of each
score is their rank in the bag, their **combined score** the smallest of the three, and the
person's p-value (1 + #{held-out people whose combined score is at most theirs}) / (n + 1). A
person is **flagged outside the prior** when it is below `ALPHA`. A person drawn from the prior
is flagged with probability at most ALPHA whatever the scores: the bag's combined scores are a
symmetric function of the bag, so the person's rank among them is uniform when they and the
held-out people are exchangeable — exactly, with no Bonferroni factor (which would need at
least 3 / ALPHA held-out people to flag anyone, and costs power). Each score spends some of
the same ALPHA: where the distance alone does the work (the shipped prior's people against the
calibrated cohort) the spread score costs a few people (docs/fit.md). The false-alarm rate is
a property of the calibration, not of tuning; the scores only decide how often people from
elsewhere are caught.

Pure: arrays in, numbers out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from services.model.summaries import TRIALS, summary_names

ALPHA = 0.05  # flagged below this p-value: at most 5 % of the prior's people
K_NEAREST = 10
RIDGE = 0.01  # added to the reference's correlation matrix's diagonal before it is inverted
PEOPLE_PER_FEATURE = 5  # fewer reference people per varying feature: no such score
SCORES = ("distance", "inconsistency", "spread")
# Per-trial summaries, each positive, whose trial-to-trial spread is scored (`summary_names`)
SPREAD_FAMILIES = ("onset", "speed", "press", "travel", "slow")
METHOD = (
    f"three scores of the rank-normal summaries: the mean distance to the {K_NEAREST} nearest "
    "reference-table people, the largest standardised residual of a summary predicted "
    "linearly from the others, and the Mahalanobis distance of the person's trial-to-trial "
    "spreads (sd of the log of each per-trial summary); each ranked among held-out table "
    "people, the smallest of the three ranked again (conformal p-value of the combination): a "
    f"person of the prior is flagged with probability at most {ALPHA:g}"
)
_CHUNK = 512  # people scored at a time: a distance matrix of chunk × reference


def summary_columns() -> tuple[tuple[int, ...], ...]:
    """Per `SPREAD_FAMILIES` summary, its column in each trial of the summary vector."""
    at = {name: i for i, name in enumerate(summary_names())}
    return tuple(tuple(at[f"{family}_{k}"] for k in TRIALS) for family in SPREAD_FAMILIES)


@dataclass(frozen=True, slots=True)
class Spread:
    """The spread score's reference: per family its columns, the spreads' features' moments."""

    columns: tuple[tuple[int, ...], ...]  # per family, its column in each trial
    values: tuple[np.ndarray, ...]  # per family, the reference's finite spreads, sorted
    centre: np.ndarray  # per spread feature, the reference's mean (features that vary)
    scale: np.ndarray  # per spread feature, the reference's sd; 0 where it never varies
    precision: np.ndarray  # regularised inverse correlation of the features that vary

    @classmethod
    def train(cls, reference: np.ndarray, columns: Sequence[Sequence[int]]) -> Spread:
        """The spreads' features on the reference people, their centre and correlations."""
        cols = tuple(tuple(int(c) for c in family) for family in columns)
        spreads = _spreads(reference, cols)
        values = tuple(np.sort(col[np.isfinite(col)]) for col in spreads.T)
        features = _features(spreads, values)
        centre, scale = features.mean(axis=0), features.std(axis=0)
        return cls(cols, values, centre, scale,
                   _precision(features, centre, scale) if cols else np.zeros((0, 0)))

    def score(self, summaries: np.ndarray) -> np.ndarray:
        """Per person: the squared Mahalanobis distance of their spreads' features (0: none)."""
        s = np.atleast_2d(np.asarray(summaries, float))
        if not self.precision.size:
            return np.zeros(len(s))
        varies = self.scale > 1e-9
        x = _features(_spreads(s, self.columns), self.values)
        z = (x[:, varies] - self.centre[varies]) / self.scale[varies]
        return np.sum((z @ self.precision) * z, axis=1)


def _spreads(summaries: np.ndarray, columns: tuple[tuple[int, ...], ...]) -> np.ndarray:
    """Per person and family: the sd of the log of its positive values over the trials.

    NaN where fewer than 2 trials have one (a missing spread, counted by its 0/1 feature).
    """
    s = np.atleast_2d(np.asarray(summaries, float))
    out = np.full((len(s), len(columns)), np.nan)
    for j, family in enumerate(columns):
        v = s[:, list(family)]
        ok = np.isfinite(v) & (v > 0)
        logs = np.log(np.where(ok, v, 1.0))
        n = ok.sum(axis=1)
        mean = np.sum(np.where(ok, logs, 0.0), axis=1) / np.maximum(n, 1)
        ss = np.sum(np.where(ok, (logs - mean[:, None]) ** 2, 0.0), axis=1)
        two = n >= 2
        out[two, j] = np.sqrt(ss[two] / (n[two] - 1))
    return out


def _precision(features: np.ndarray, centre: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The ridge-regularised inverse correlation of the features that vary.

    Empty when there are fewer than `PEOPLE_PER_FEATURE` people per feature that varies.
    """
    varies = scale > 1e-9
    if len(features) < PEOPLE_PER_FEATURE * max(int(np.count_nonzero(varies)), 1):
        return np.zeros((0, 0))
    z = (features[:, varies] - centre[varies]) / scale[varies]
    corr = z.T @ z / max(len(z) - 1, 1)
    return np.linalg.inv(corr + RIDGE * np.eye(len(corr)))


@dataclass(frozen=True, slots=True)
class PriorCheck:
    """The reference people's features, and the calibration scores of held-out ones."""

    values: tuple[np.ndarray, ...]  # per summary, the reference's finite values, sorted
    reference: np.ndarray  # reference people × features
    centre: np.ndarray  # per feature, the reference's mean (features that vary)
    spread: np.ndarray  # per feature, the reference's sd; 0 where it never varies
    precision: np.ndarray  # regularised inverse correlation of the features that vary
    trial_spread: Spread  # the spread score's reference
    calibration: np.ndarray  # held-out people × scores
    at_least: np.ndarray  # held-out people × scores: how many held-out scores are ≥ each

    @classmethod
    def train(cls, reference: np.ndarray, held_out: np.ndarray,
              spread_columns: Sequence[Sequence[int]] = ()) -> PriorCheck:
        """Rank by the reference's summaries; calibrate on the held-out people's scores.

        `spread_columns`: per summary measured in every trial, its columns (the fit's:
        `summary_columns()`); none: no spread score.
        """
        reference = np.atleast_2d(np.asarray(reference, float))
        values = tuple(np.sort(col[np.isfinite(col)]) for col in reference.T)
        features = _features(reference, values)
        centre, spread = features.mean(axis=0), features.std(axis=0)
        # too few people to estimate the correlations: no inconsistency, the distance alone
        precision = _precision(features, centre, spread)
        # the spread only beside the inconsistency: a small table's calibration affords one score
        trial_spread = Spread.train(reference, spread_columns if precision.size else ())
        empty = np.zeros((0, len(SCORES)))
        unscored = cls(values, features, centre, spread, precision, trial_spread, empty, empty)
        cal = unscored.scores(held_out)
        at_least = np.stack([len(col) - np.searchsorted(np.sort(col), col, side="left")
                             for col in cal.T], axis=1)
        return cls(values, features, centre, spread, precision, trial_spread, cal, at_least)

    def scores(self, summaries: np.ndarray) -> np.ndarray:
        """Per person (rows), each of `SCORES` (columns): larger is less like the prior."""
        x = _features(summaries, self.values)
        return np.stack([self._distance(x), self._inconsistency(x),
                         self.trial_spread.score(summaries)], axis=1)

    def _distance(self, x: np.ndarray) -> np.ndarray:
        """Per person: the mean distance to their `K_NEAREST` nearest reference people."""
        ref = self.reference
        k = min(K_NEAREST, len(ref))
        ref_sq = np.sum(ref * ref, axis=1)
        out = np.empty(len(x))
        for start in range(0, len(x), _CHUNK):
            part = x[start:start + _CHUNK]
            d2 = np.sum(part * part, axis=1)[:, None] + ref_sq[None, :] - 2.0 * part @ ref.T
            nearest = np.partition(np.maximum(d2, 0.0), k - 1, axis=1)[:, :k]
            out[start:start + _CHUNK] = np.mean(np.sqrt(nearest), axis=1)
        return out

    def _inconsistency(self, x: np.ndarray) -> np.ndarray:
        """Per person: the largest squared residual of a feature predicted from the others.

        A feature the reference never varies counts only through the distance; with fewer than
        `PEOPLE_PER_FEATURE` reference people per feature that varies, every feature does (the
        score is 0 for everyone, and the check is the distance's alone).
        """
        varies = self.spread > 1e-9
        if not self.precision.size:
            return np.zeros(len(x))
        z = (x[:, varies] - self.centre[varies]) / self.spread[varies]
        residual = (z @ self.precision) / np.sqrt(np.diag(self.precision))
        return np.max(residual * residual, axis=1)

    def p_values(self, summaries: np.ndarray) -> np.ndarray:
        """Per person (rows), each score's conformal p-value among the held-out people's."""
        s = self.scores(summaries)
        n = len(self.calibration)
        at_least = np.stack([n - np.searchsorted(np.sort(col), s[:, j], side="left")
                             for j, col in enumerate(self.calibration.T)], axis=1)
        return (1.0 + at_least) / (n + 1.0)

    def p_value(self, summaries: np.ndarray) -> np.ndarray:
        """Per person: the conformal p-value of their combined score (module docstring).

        The combined score of each member of the bag (the held-out people and the person) is
        the smallest of their per-score ranks in the bag; the p-value is the person's place
        among them, ties counted against the person.
        """
        s = self.scores(summaries)
        cal, n = self.calibration, len(self.calibration)
        own = 1 + np.sum(cal[None, :, :] >= s[:, None, :], axis=1).min(axis=1)  # person's
        out = np.empty(len(s))
        for start in range(0, len(s), _CHUNK // 8):
            part = s[start:start + _CHUNK // 8]
            # each held-out person's rank in the bag: among the held-out, plus the person
            bag = self.at_least[None, :, :] + (part[:, None, :] >= cal[None, :, :])
            combined = bag.min(axis=2)  # chunk × held-out
            mine = own[start:start + _CHUNK // 8]
            out[start:start + _CHUNK // 8] = (
                1.0 + np.sum(combined <= mine[:, None], axis=1)) / (n + 1.0)
        return out

    def outside(self, summaries: np.ndarray, alpha: float = ALPHA) -> np.ndarray:
        """Per person: flagged outside the prior (p-value below `alpha`)."""
        return self.p_value(summaries) < alpha


def _features(summaries: np.ndarray, values: tuple[np.ndarray, ...]) -> np.ndarray:
    """Normal scores of the summaries among the reference's (a missing one 0); 0/1 per missing.

    A summary the reference never has is 0 wherever it is present: its 0/1 feature alone tells.
    """
    from scipy.stats import norm

    s = np.atleast_2d(np.asarray(summaries, float))
    missing = ~np.isfinite(s)
    z = np.zeros_like(s)
    for j, ref in enumerate(values):
        if len(ref):
            rank = 0.5 * (np.searchsorted(ref, s[:, j], "left")
                          + np.searchsorted(ref, s[:, j], "right"))
            z[:, j] = norm.ppf((rank + 0.5) / (len(ref) + 1))
    z[missing] = 0.0
    return np.concatenate([z, missing.astype(float)], axis=1)
