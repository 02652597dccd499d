"""The estimator: per parameter, conditional quantiles of the prior given a person's summaries.

Amortised simulation-based inference: scikit-learn's `HistGradientBoostingRegressor` with the
pinball loss learns, from the reference table, the 5 %, 50 % and 95 % quantiles of each
parameter given the summaries (missing summaries, NaN, are handled natively). The median is
the estimate; the 90 % interval is conformalised (Romano et al. 2019, CQR): the two outer
quantile models are widened by the (1 − α)(1 + 1/n) quantile of their misses on a calibration
split, so the interval's coverage over the prior holds however the boosting over- or
under-fits. A 0/1 parameter (a kind) is reported as its most likely value, its probability and
its 90 % set, conformalised on the same split (`_raw`); every estimate lies inside its own
interval or set (`Estimates`). A third split checks each parameter as a recovery study does
(correlation of true and estimated, bias, coverage): the verdict `identifiable` of `nod fit`.

The model-recovery check (`ModelClassifier`) is a `HistGradientBoostingClassifier` on the same
summaries: which of two descriptions made a session (with the gaze term or without; the fit's
prior or another population, `nod fit recovery --versus`).

The estimate as a session goes (`ByLength`, `estimate_after`): one `QuantileEstimator` per
session length k = 1..8, each trained on the same reference table read as if only its first k
trials had been played (`services.model.summaries.first_trials`), so each length's intervals
are calibrated, and checked, at that length; at k = 8 it is the complete-session estimator.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Any

import numpy as np

from services.model.geometry import TableLayout
from services.model.recovery import Recovery, recovery
from services.model.summaries import TRIALS, TrialPath, first_trials, summarise

LEVEL = 0.90  # the intervals' nominal coverage
ALPHA_SET = 1 - LEVEL  # before calibration, a 0/1 parameter's set: the values at least this likely
SPLITS = (0.70, 0.15)  # train, calibrate; the rest checks
# 120 rounds at rate 0.1: as good on the checks as 250 at 0.06, in half the time.
BOOSTING: dict[str, Any] = dict(learning_rate=0.1, max_iter=120, max_leaf_nodes=15,
                                min_samples_leaf=20, l2_regularization=1.0)


@dataclass(frozen=True, slots=True)
class Estimates:
    """Per person (rows) and parameter (columns): estimate and the 90 % interval or set.

    A 0/1 parameter's estimate is its most likely value (1 when its probability is at least
    ½), `probability` its probability of 1, and low/high the least and largest value of its
    90 % set ({0}, {1} or {0, 1}): so that every estimate lies inside its own interval or set,
    and a reader of the estimate column never takes a probability for a value. `probability`
    is NaN for the other parameters.
    """

    names: tuple[str, ...]
    estimate: np.ndarray
    low: np.ndarray
    high: np.ndarray
    probability: np.ndarray

    @property
    def graded(self) -> np.ndarray:
        """The estimates with a 0/1 parameter's probability in place of its most likely value.

        What the recovery check correlates and the posterior draws match on: the probability
        grades people that the most likely value lumps into two, and the checks' verdicts stay
        those of the estimator as it was trained.
        """
        return np.where(np.isnan(self.probability), self.estimate, self.probability)


def _boosting(rows: int) -> dict[str, Any]:
    """The boosting's settings for `rows` of training data.

    Fewer rounds when there is less to learn: a test's table of 20 people trains in a second,
    not in twenty.
    """
    return {**BOOSTING, "max_iter": min(BOOSTING["max_iter"], max(10, rows // 10))}


def one_thread() -> AbstractContextManager[object]:
    """scikit-learn's OpenMP held to one thread.

    On a shared or busy machine (the engine's workers run beside it) two spinning OpenMP
    threads trained 30× slower than one.
    """
    from threadpoolctl import threadpool_limits

    return threadpool_limits(1)


def _split(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    order = np.random.default_rng(seed).permutation(n)
    a, b = int(SPLITS[0] * n), int((SPLITS[0] + SPLITS[1]) * n)
    return order[:a], order[a:b], order[b:]


def _kind(values: np.ndarray) -> str:
    """How a parameter is learnt: "binary" (0/1), "log" (positive, spanning a decade) or "linear".

    A log-normal trait (gaze_gain) is learnt on its log, where its spread is even; quantiles
    carry over through exp unchanged. A 0/1 trait gets a classifier: a quantile of a 0/1 value
    is 0 or 1 and says nothing of how likely either is.
    """
    if np.isin(values, (0.0, 1.0)).all():
        return "binary"
    if values.min() > 0 and values.max() > 10 * values.min():
        return "log"
    return "linear"


class QuantileEstimator:
    """Trained once on a reference table; `predict` fits any number of people at once.

    A 0/1 parameter's estimate is its most likely value, beside its probability; its 90 % set
    is {0}, {1} or {0, 1}: every value whose probability is at least 10 %.
    """

    def __init__(self, names: Sequence[str], seed: int = 0) -> None:
        """An untrained estimator of these parameters."""
        self.names = tuple(names)
        self.seed = seed
        self._models: list[tuple[Any, ...]] = []
        self._kinds: list[str] = []
        self._margin = np.zeros(len(self.names))
        # A 0/1 parameter's set holds each value v with 1 − P(v) at most this (conformal).
        self._threshold = np.full(len(self.names), 1 - ALPHA_SET)
        self._columns = np.zeros(0, dtype=int)
        self.held_out = np.zeros(0, dtype=int)
        self.check: list[Recovery] = []

    def train(self, theta: np.ndarray, summaries: np.ndarray) -> QuantileEstimator:
        """Learn the quantiles on the table; calibrate the intervals; check recovery."""
        with one_thread():
            return self._train(theta, summaries)

    def _train(self, theta: np.ndarray, summaries: np.ndarray) -> QuantileEstimator:
        from sklearn.ensemble import HistGradientBoostingClassifier, HistGradientBoostingRegressor

        train, calib, check = _split(len(theta), self.seed)
        self.held_out = np.sort(np.concatenate([calib, check]))  # rows it never learnt from
        # A summary the table never shows (a turn no one made) carries nothing, and
        # scikit-learn's binning fails on an all-missing column.
        self._columns = np.flatnonzero(np.isfinite(summaries[train]).any(axis=0))
        summaries = summaries[:, self._columns]
        alpha = (1 - LEVEL) / 2
        self._models, self._kinds = [], []
        for p in range(len(self.names)):
            kind = _kind(theta[train, p])
            y = np.log(theta[train, p]) if kind == "log" else theta[train, p]
            if kind == "binary" and len(set(y)) < 2:
                kind = "constant"  # everyone alike in the table: nothing to learn
                models: tuple[Any, ...] = (float(y[0]),)
            elif kind == "binary":
                models = (HistGradientBoostingClassifier(
                    random_state=self.seed, **_boosting(len(y))).fit(summaries[train], y),)
            else:
                models = tuple(
                    HistGradientBoostingRegressor(
                        loss="quantile", quantile=q, random_state=self.seed, **_boosting(len(y))
                    ).fit(summaries[train], y)
                    for q in (alpha, 0.5, 1 - alpha)
                )
            self._models.append(models)
            self._kinds.append(kind)
        self._margin = np.zeros(len(self.names))
        self._threshold = np.full(len(self.names), 1 - ALPHA_SET)
        raw = self._raw(summaries[calib])
        for p, kind in enumerate(self._kinds):
            if kind == "constant":
                continue
            q = min(1.0, LEVEL * (1 + 1 / len(calib)))
            if kind == "binary":  # the set's nonconformity: 1 − the probability of the truth
                prob = raw.estimate[:, p]
                scores = np.where(theta[calib, p] >= 0.5, 1.0 - prob, prob)
                self._threshold[p] = float(np.quantile(scores, q, method="higher"))
                continue
            y = np.log(theta[calib, p]) if kind == "log" else theta[calib, p]
            misses = np.maximum(raw.low[:, p] - y, y - raw.high[:, p])
            self._margin[p] = float(np.quantile(misses, q, method="higher"))
        fit = self._finish(self._raw(summaries[check]))
        self.check = [
            recovery(n, theta[check, p], fit.graded[:, p], fit.low[:, p], fit.high[:, p],
                     log=self.log_scaled[p])
            for p, n in enumerate(self.names)
        ]
        return self

    @property
    def log_scaled(self) -> tuple[bool, ...]:
        """Per parameter: learnt on its log (a log-normal trait), so recovered on its log too."""
        return tuple(kind == "log" for kind in self._kinds)

    def _raw(self, summaries: np.ndarray) -> Estimates:
        """Per parameter (learning scale): the three quantiles, or p and its 90 % set.

        A 0/1 parameter's set is conformal (adaptive prediction sets, Romano, Sesia & Candès
        2020, for two classes): each value whose probability's shortfall from 1 is within the
        calibration people's 90 % quantile of it, so the sets hold the truth for 90 % of the
        prior's people however well or badly the classifier's probabilities are calibrated.
        """
        n = len(summaries)
        q = np.zeros((n, len(self.names), 3))
        for p, (kind, models) in enumerate(zip(self._kinds, self._models, strict=True)):
            if kind == "constant":
                q[:, p, :] = models[0]
            elif kind == "binary":
                prob = models[0].predict_proba(summaries)[:, 1]
                t = self._threshold[p]  # an empty set is given its likelier value (`_finish`)
                q[:, p, 0] = np.where(prob <= t, 0.0, 1.0)
                q[:, p, 1] = prob
                q[:, p, 2] = np.where(1.0 - prob <= t, 1.0, 0.0)
            else:
                q[:, p, :] = np.sort(np.stack([m.predict(summaries) for m in models], axis=1),
                                     axis=1)
        return Estimates(self.names, q[:, :, 1], q[:, :, 0], q[:, :, 2],
                         np.full((n, len(self.names)), np.nan))

    def _finish(self, raw: Estimates) -> Estimates:
        """Widen by the conformal margins, back on the parameters' own scale.

        A 0/1 parameter's probability (the raw estimate) becomes its own field and its estimate
        the most likely value. The interval is stretched to hold the estimate: a conformal
        margin below 0 (quantile models wider than their misses need) narrows the interval and
        could leave the median outside; taking it in again only widens the interval, so the
        coverage the calibration gives is kept.
        """
        low, high = raw.low - self._margin, raw.high + self._margin
        est = raw.estimate.copy()
        prob = np.full_like(est, np.nan)
        for p, kind in enumerate(self._kinds):
            if kind == "log":
                est[:, p], low[:, p], high[:, p] = (np.exp(v[:, p]) for v in (est, low, high))
            elif kind in ("binary", "constant"):  # a constant is a 0/1 trait no one varies in
                prob[:, p] = est[:, p]
                est[:, p] = np.where(est[:, p] >= 0.5, 1.0, 0.0)
        return Estimates(self.names, est, np.minimum(low, est), np.maximum(high, est), prob)

    def predict(self, summaries: np.ndarray) -> Estimates:
        """Estimates and conformalised 90 % intervals for people's summaries (n × F)."""
        with one_thread():
            return self._finish(self._raw(np.atleast_2d(summaries)[:, self._columns]))


class ByLength:
    """The estimator after 1, 2, … 8 trials: one `QuantileEstimator` per session length.

    Each is trained on the same table, its summaries cut to the first k trials, with the same
    seed (so the same split of the table): the one for k = 8 is the complete-session
    estimator, trained on the same numbers.
    """

    def __init__(self, names: Sequence[str], seed: int = 0) -> None:
        """Untrained estimators of these parameters, one per length."""
        self.names = tuple(names)
        self.seed = seed
        self.at: dict[int, QuantileEstimator] = {}

    def train(self, theta: np.ndarray, summaries: np.ndarray,
              lengths: Sequence[int] = TRIALS) -> ByLength:
        """Train (and check) the estimator of each length on the table cut to that length."""
        self.at = {k: QuantileEstimator(self.names, self.seed).train(
            theta, first_trials(summaries, k)) for k in lengths}
        return self

    def predict(self, k: int, summaries: np.ndarray) -> Estimates:
        """Estimates after k trials, from sessions' summaries (only their first k trials read)."""
        return self.at[k].predict(first_trials(np.atleast_2d(summaries), k))


def estimate_after(estimators: ByLength, k: int, trials_so_far: Sequence[TrialPath],
                   layout: TableLayout) -> Estimates:
    """One person's estimates and 90 % intervals after their first k trials (one row).

    Only the trials numbered 1..k are read, whatever else `trials_so_far` holds; a trial among
    them that is missing or interrupted counts as one with nothing to read, as in `nod fit`.
    """
    played = [t for t in trials_so_far if 1 <= t.trial <= k]
    return estimators.predict(k, summarise(played, layout))


class ModelClassifier:
    """Which of two descriptions made a session? Trained on sessions simulated by each."""

    def __init__(self, seed: int = 0) -> None:
        """An untrained classifier."""
        self.seed = seed
        self._model: object | None = None

    def train(self, first: np.ndarray, second: np.ndarray) -> ModelClassifier:
        """Learn from summaries of sessions of the first (label 1) and second (0) description."""
        from sklearn.ensemble import HistGradientBoostingClassifier

        x = np.concatenate([first, second])
        y = np.concatenate([np.ones(len(first)), np.zeros(len(second))])
        with one_thread():
            self._model = HistGradientBoostingClassifier(
                random_state=self.seed, **_boosting(len(y))
            ).fit(x, y)
        return self

    def accuracy(self, first: np.ndarray, second: np.ndarray) -> float:
        """The share of held-out sessions classified right."""
        assert self._model is not None, "train first"
        x = np.concatenate([first, second])
        y = np.concatenate([np.ones(len(first)), np.zeros(len(second))])
        with one_thread():
            return float(np.mean(self._model.predict(x) == y))  # type: ignore[attr-defined]
