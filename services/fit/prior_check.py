"""Is a person inside the prior? Two summary scores, each calibrated on the prior's own people.

The fit's intervals are calibrated over the prior: they say nothing of a person the prior
cannot produce. So each person's summaries are checked against the reference table before
their estimates are read. Every summary is read as its normal score among the reference's
values of it (its mid-rank, through the inverse normal: a press time of 12 s counts as far out
as the rank says, not as its seconds would), a missing summary (a timeout, a turn never made)
counted by its own 0/1 feature instead of a value. Two scores of those features:

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
  on a smaller table the check is the distance's alone.

**The calibration** is split-conformal novelty detection (Bates, Candès, Lei, Romano & Sesia
2023, "Testing for outliers with conformal p-values"), on the held-out table people (people of
the prior the reference does not hold). Each score's p-value is the person's rank among the
held-out people's, (1 + #{held-out scores ≥ theirs}) / (n + 1); the two are combined by
ranking again: in the bag of the n held-out people and the person, everyone's p-value of each
score is their rank in the bag, their **combined score** the smaller of the two, and the
person's p-value (1 + #{held-out people whose combined score is at most theirs}) / (n + 1). A
person is **flagged outside the prior** when it is below `ALPHA`. A person drawn from the prior
is flagged with probability at most ALPHA whatever the scores: the bag's combined scores are a
symmetric function of the bag, so the person's rank among them is uniform when they and the
held-out people are exchangeable — exactly, with no Bonferroni factor (which would need at
least 2 / ALPHA held-out people to flag anyone, and costs power). The false-alarm rate is a
property of the calibration, not of tuning; the scores only decide how often people from
elsewhere are caught.

Pure: arrays in, numbers out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ALPHA = 0.05  # flagged below this p-value: at most 5 % of the prior's people
K_NEAREST = 10
RIDGE = 0.01  # added to the reference's correlation matrix's diagonal before it is inverted
PEOPLE_PER_FEATURE = 5  # fewer reference people per varying feature: no inconsistency score
SCORES = ("distance", "inconsistency")
METHOD = (
    f"two scores of the rank-normal summaries: the mean distance to the {K_NEAREST} nearest "
    "reference-table people, and the largest standardised residual of a summary predicted "
    "linearly from the others; each ranked among held-out table people, the smaller of the "
    "two ranked again (conformal p-value of the combination): a person of the prior is flagged "
    f"with probability at most {ALPHA:g}"
)
_CHUNK = 512  # people scored at a time: a distance matrix of chunk × reference


@dataclass(frozen=True, slots=True)
class PriorCheck:
    """The reference people's features, and the calibration scores of held-out ones."""

    values: tuple[np.ndarray, ...]  # per summary, the reference's finite values, sorted
    reference: np.ndarray  # reference people × features
    centre: np.ndarray  # per feature, the reference's mean (features that vary)
    spread: np.ndarray  # per feature, the reference's sd; 0 where it never varies
    precision: np.ndarray  # regularised inverse correlation of the features that vary
    calibration: np.ndarray  # held-out people × scores
    at_least: np.ndarray  # held-out people × scores: how many held-out scores are ≥ each

    @classmethod
    def train(cls, reference: np.ndarray, held_out: np.ndarray) -> PriorCheck:
        """Rank by the reference's summaries; calibrate on the held-out people's scores."""
        reference = np.atleast_2d(np.asarray(reference, float))
        values = tuple(np.sort(col[np.isfinite(col)]) for col in reference.T)
        features = _features(reference, values)
        centre, spread = features.mean(axis=0), features.std(axis=0)
        varies = spread > 1e-9
        if len(features) >= PEOPLE_PER_FEATURE * np.count_nonzero(varies):
            z = (features[:, varies] - centre[varies]) / spread[varies]
            corr = z.T @ z / max(len(z) - 1, 1)
            precision = np.linalg.inv(corr + RIDGE * np.eye(len(corr)))
        else:  # too few people to estimate the correlations: the distance alone
            precision = np.zeros((0, 0))
        empty = np.zeros((0, len(SCORES)))
        unscored = cls(values, features, centre, spread, precision, empty, empty)
        cal = unscored.scores(held_out)
        at_least = np.stack([len(col) - np.searchsorted(np.sort(col), col, side="left")
                             for col in cal.T], axis=1)
        return cls(values, features, centre, spread, precision, cal, at_least)

    def scores(self, summaries: np.ndarray) -> np.ndarray:
        """Per person (rows), each of `SCORES` (columns): larger is less like the prior."""
        x = _features(summaries, self.values)
        return np.stack([self._distance(x), self._inconsistency(x)], axis=1)

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
