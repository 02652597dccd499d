"""Is a person inside the prior? A summary-distance check, calibrated on the prior's own people.

The fit's intervals are calibrated over the prior: they say nothing of a person the prior
cannot produce. So each person's summaries are checked against the reference table before
their estimates are read:

- **the score** is the mean distance from the person's summaries to their `K_NEAREST` nearest
  table people (the reference: the rows the estimator learnt from), each summary read as its
  normal score among the reference's values of it (its mid-rank, through the inverse normal:
  a press time of 12 s counts as far out as the rank says, not as its seconds would), a missing
  summary (a timeout, a turn never made) counted by its own 0/1 feature instead of a value: no
  one in the prior looks like someone far from all of them. On the reference tables the normal
  scores caught more people of other populations than summaries scaled by their sd (split
  person: 0.36 against 0.31 flagged under the shipped prior; docs/fit.md);
- **the calibration** is split-conformal novelty detection (Bates, Candès, Lei, Romano &
  Sesia 2023, "Testing for outliers with conformal p-values"): the same score of every held-out
  table person (people of the prior the reference does not hold) gives a person's p-value, (1 +
  #{held-out scores ≥ theirs}) / (n + 1), and a person is **flagged outside the prior** when
  it is below `ALPHA`. A person drawn from the prior is flagged with probability at most ALPHA
  whatever the score (the held-out people and they are exchangeable): the false-alarm rate is
  a property of the calibration, not of tuning; the score only decides how often people from
  elsewhere are caught.

Pure: arrays in, numbers out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ALPHA = 0.05  # flagged below this p-value: at most 5 % of the prior's people
K_NEAREST = 10
_CHUNK = 512  # people scored at a time: a distance matrix of chunk × reference


@dataclass(frozen=True, slots=True)
class PriorCheck:
    """The reference people's features, and the calibration scores of held-out ones."""

    values: tuple[np.ndarray, ...]  # per summary, the reference's finite values, sorted
    reference: np.ndarray  # reference people × features
    calibration: np.ndarray  # held-out people's scores, sorted

    @classmethod
    def train(cls, reference: np.ndarray, held_out: np.ndarray) -> PriorCheck:
        """Rank by the reference's summaries; calibrate on the held-out people's scores."""
        reference = np.atleast_2d(np.asarray(reference, float))
        values = tuple(np.sort(col[np.isfinite(col)]) for col in reference.T)
        unscored = cls(values, _features(reference, values), np.zeros(0))
        return cls(values, unscored.reference, np.sort(unscored.score(held_out)))

    def score(self, summaries: np.ndarray) -> np.ndarray:
        """Per person: the mean distance to their `K_NEAREST` nearest reference people."""
        x = _features(summaries, self.values)
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

    def p_value(self, summaries: np.ndarray) -> np.ndarray:
        """Per person: the conformal p-value of their score among the held-out people's."""
        s = self.score(summaries)
        n = len(self.calibration)
        at_least = n - np.searchsorted(self.calibration, s, side="left")
        return (1.0 + at_least) / (n + 1.0)

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
