"""The fit's steps, shared by `nod fit` and `nod fit recovery` so both fit people the same way.

`prepare`: the reference table (cached), the estimator trained on it and the out-of-prior check
calibrated on it (`prior_check`: the table people the estimator learnt from are its reference,
the others its calibration). `posterior_draws`: a
person's posterior sample, by semi-automatic ABC (Fearnhead & Prangle 2012): the table people
(of those the estimator did not learn from) whose estimated parameters lie nearest to the
person's (the regression's estimates are the summary statistics) — their true parameters,
jointly, so the dependence between parameters (gaze_gain × trust0) is kept. `predictive`: new
sessions of those draws, for the posterior-predictive check. `prepare_by_length`: the
estimators after 1, 2, … 8 trials (`ByLength`) on the same table, cached beside it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import pickle
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np

from services.fit.estimator import ByLength, Estimates, QuantileEstimator
from services.fit.prior import DERIVED, SHARE_OF, person_params
from services.fit.prior_check import PriorCheck, summary_columns
from services.fit.simulate import (
    Mapper,
    Population,
    Simulated,
    Table,
    reference_table,
    simulate_given,
)
from services.model.params import NodConfig

E = TypeVar("E", QuantileEstimator, ByLength)
PREDICTIVE_SEED = 2 * 10**9  # predictive sessions' seeds: never a study's or the table's


@dataclass(frozen=True)
class Prepared:
    """A trained fit: its table and estimator."""

    table: Table
    estimator: QuantileEstimator
    cached: bool  # the table came from the cache
    trained: bool  # the estimator was trained now (False: read from the cache)
    table_estimates: Estimates  # the estimator on the table people it never learnt from
    prior_check: PriorCheck  # is a person's summaries like the table's people?

    @property
    def identifiable(self) -> dict[str, bool]:
        """Each parameter's verdict on the table's held-out check."""
        return {r.name: r.identifiable for r in self.estimator.check}


def prepare(pop: Population, k: int, run: Mapper, cache: Path | None, seed: int = 0
            ) -> Prepared:
    """The reference table of K people and the estimator trained on it, each cached on disk."""
    table, cached = reference_table(pop, k, run, cache)
    estimator, trained = _trained(
        QuantileEstimator(table.names, seed), table, cached,
        cache / f"estimator-{pop.key()}-{k}-{estimator_digest()}-{seed}.pickle"
        if cache is not None else None)
    held = estimator.held_out
    learnt = np.setdiff1d(np.arange(len(table.summaries)), held)
    check = PriorCheck.train(table.summaries[learnt], table.summaries[held], summary_columns())
    return Prepared(table, estimator, cached, trained, estimator.predict(table.summaries[held]),
                    check)


def prepare_by_length(pop: Population, k: int, run: Mapper, cache: Path | None,
                      seed: int = 0) -> tuple[Table, ByLength, bool]:
    """The table of K people, the estimators after 1..8 trials (cached), and trained now."""
    table, cached = reference_table(pop, k, run, cache)
    estimators, trained = _trained(
        ByLength(table.names, seed), table, cached,
        cache / f"by-length-{pop.key()}-{k}-{estimator_digest()}-{seed}.pickle"
        if cache is not None else None)
    return table, estimators, trained


def _trained(untrained: E, table: Table, cached: bool, path: Path | None) -> tuple[E, bool]:
    """An estimator read from `path` if the table was cached, else trained and kept there."""
    estimator = _load(path, type(untrained)) if cached and path is not None else None
    if estimator is not None:
        return estimator, False
    estimator = untrained.train(table.theta, table.summaries)
    if path is not None:
        tmp = path.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps(estimator))
        tmp.replace(path)
    return estimator, True


def estimator_digest() -> str:
    """The source of training and its checks: an estimator cached by other code is retrained.

    (A hand-bumped version number was missed once: a pickled estimator of the code before
    carried `Recovery` objects without a field the new code reads.)
    """
    from services.fit import estimator
    from services.model import recovery

    digest = hashlib.sha256()
    for module in (estimator, recovery):
        digest.update(Path(str(module.__file__)).read_bytes())
    return digest.hexdigest()[:12]


def _load(path: Path, kind: type[E]) -> E | None:
    """A cached estimator (our own file in our own cache), None if absent or unreadable."""
    try:
        estimator = pickle.loads(path.read_bytes())
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError):
        return None
    return estimator if isinstance(estimator, kind) else None


def posterior_draws(prep: Prepared, estimate: np.ndarray, n: int) -> np.ndarray:
    """The parameters of the n table people nearest to a person's estimates (n × P)."""
    theta = prep.table.theta[prep.estimator.held_out]  # estimates out of sample, as a person's
    est = prep.table_estimates.graded  # a kind by its probability, as the check reads it
    scale = np.std(theta, axis=0)
    scale[scale == 0] = 1.0
    d = np.sum(((est - estimate) / scale) ** 2, axis=1)
    return theta[np.argsort(d)[:n]]


def person_config(pop: Population, names: Sequence[str], theta: np.ndarray) -> NodConfig:
    """The population's configuration with one person's traits (derived parameters ignored).

    A kind the prior states but the fit does not estimate (probability 0 or 1) is everyone's
    or no one's; one it does not state keeps the cohort's share.
    """
    traits: dict[str, float] = {}
    kinds = {kind: p >= 1 for kind, p in pop.prior.kinds}
    for name, value in zip(names, theta, strict=True):
        if name in SHARE_OF:  # someone of that kind for sure, or not at all
            kinds[name] = bool(value >= 0.5)
        elif name not in DERIVED:
            traits[name] = float(value)
    cfg = pop.cfg
    return dataclasses.replace(cfg, participant=person_params(cfg.participant, traits, kinds))


def predictive(pop: Population, prep: Prepared, estimates: Estimates, draws: int,
               run: Mapper) -> list[list[Simulated]]:
    """Per person, `draws` new sessions of their posterior draws (empty lists for 0 draws)."""
    draws = min(draws, len(prep.estimator.held_out))
    if draws <= 0:
        return [[] for _ in range(len(estimates.estimate))]
    jobs: list[tuple[NodConfig, int]] = []
    for i, est in enumerate(estimates.graded):
        for j, theta in enumerate(posterior_draws(prep, est, draws)):
            jobs.append((person_config(pop, prep.table.names, theta),
                         PREDICTIVE_SEED + i * draws + j))
    sims = run(simulate_given, jobs)
    return [sims[i * draws:(i + 1) * draws] for i in range(len(estimates.estimate))]
