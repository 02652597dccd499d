"""The cohort calibration's search: CMA-ES (pycma, ask/tell) over the participant's traits.

Each trait is searched in its range, mapped to [0, 1] so that one step size fits all; pycma's
bounds [0, 1] with its default boundary handler (`BoundTransform`: every candidate it hands out
is inside the box, and the search still sees a smooth landscape near a bound). CMA-ES rather than
a hand-written search: it is a kept library, it adapts step sizes and correlations between
traits itself (speed and conviction trade off, trust and gaze gain too), it asks for a whole
generation at once — so a generation's candidates are simulated in parallel on the engine — and
it tolerates the noise of a cohort of finite size better than a simplex does.

- sigma0 = 0.2 of each trait's range: pycma's guide puts the initial step at 1/4–1/5 of the
  search box, so the first generations explore the whole box around the start.
- popsize = pycma's default, 4 + ⌊3 ln n⌋ (10 for 10 traits, 11 for 11–14): the smallest
  population it recommends for a reliable covariance update; with a fixed budget, more
  generations beat a larger population.
- the start (the `--params` / shipped traits) is injected into the first generation, so a refit
  is never worse on the fit's seeds than where it began.

Common random numbers: every candidate of every generation is scored on the same participants
(seeds seed..seed+n−1), so two candidates differ by their traits, not by who was drawn.
The score is Σ over trials of the TVD of the per-trial shares, plus a weight (FLOW_WEIGHT,
`--flow-weight`) × the TVD of the Fig 8b flows (who is C in control tends to stay C: a
person-level property the marginals cannot see). At weight 1 the flows are one term against
eight trials, so a search trades a lot of flow distance for a little trial distance; a larger
weight asks for the person-level consistency more.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import cma
import numpy as np

from services.cohort.outcomes import (
    Flows,
    Outcomes,
    Shares,
    flows,
    session_outcomes,
    shares,
    tvd,
)
from services.compute.engine import Engine
from services.model.params import NodConfig

SIGMA0 = 0.2  # the first generation's step, as a share of each trait's range
FLOW_WEIGHT = 1.0  # by default the Fig 8b flows count as much as one trial


@dataclass(frozen=True)
class Trait:
    """One fitted participant trait (a float field of ParticipantParams) and its search range."""

    name: str
    low: float
    high: float


# One line per fitted trait; what each one means is in services/model/participant.py.
TRAITS: tuple[Trait, ...] = (
    Trait("control_switch_prob", 0.0, 1.0),
    Trait("preference_mean", 0.5, 5.0),
    # How the preference's variance splits: trial to trial (sd) and person to person (spread).
    Trait("preference_sd", 0.05, 1.0),
    Trait("preference_spread", 0.0, 1.2),
    Trait("gaze_gain", 1.0, 15.0),
    Trait("gaze_gain_spread", 0.0, 1.5),
    Trait("trust0", 0.0, 2.0),
    Trait("trust_step", 0.0, 0.6),
    Trait("gaze_over_robot", 0.0, 5.0),
    Trait("speed", 0.2, 0.6),
    # Not bounded to keep the hand's speed carrying conviction: a fit held there (full 0.25,
    # min 0.24) was further from the paper on held-out people (docs/fit.md).
    Trait("full_conviction", 0.1, 1.0),
    Trait("min_conviction", 0.0, 1.0),
    # The strategic late switch of control trials (participant.py; its lead stays fixed at 0.1:
    # turns started closer to the commit line are read past it, as rule violations).
    Trait("late_switch_share", 0.0, 0.8),
    Trait("late_switch_first", 0.0, 1.0),
    Trait("late_switch_learn", 0.0, 1.0),
    Trait("late_switch_speed", 1.0, 2.5),
    # The person who distrusts the eyes in consensus trials (participant.py).
    Trait("contrarian_share", 0.0, 0.6),
    Trait("contrarian_learn", 0.0, 1.0),
    Trait("contrarian_resolve", 0.0, 1.5),
    Trait("contrarian_firm", 0.0, 1.0),
    Trait("contrarian_persist", 0.0, 1.0),
)


def default_popsize(dims: int) -> int:
    """The default population size of pycma for `dims` traits."""
    return 4 + int(3 * math.log(dims))


def to_unit(cfg: NodConfig, traits: Sequence[Trait] = TRAITS) -> np.ndarray:
    """The config's traits as a point of [0, 1]^k (clipped into the ranges)."""
    return np.array([
        (getattr(cfg.participant, t.name) - t.low) / (t.high - t.low) for t in traits
    ]).clip(0.0, 1.0)


def from_unit(
    unit: Sequence[float] | np.ndarray, traits: Sequence[Trait] = TRAITS
) -> dict[str, float]:
    """The trait values a point of [0, 1]^k stands for."""
    u = np.clip(np.asarray(unit, dtype=float), 0.0, 1.0)
    return {t.name: t.low + (t.high - t.low) * float(x) for t, x in zip(traits, u, strict=True)}


def with_traits(cfg: NodConfig, values: dict[str, float]) -> NodConfig:
    """The config with the participant's traits replaced."""
    person = replace(cfg.participant, **values)  # type: ignore[arg-type]  # float fields
    return replace(cfg, participant=person)


def score(
    cohort: Sequence[Outcomes],
    target: Shares,
    target_flows: Flows,
    flow_weight: float = FLOW_WEIGHT,
) -> float:
    """Σ_trials TVD(shares, target) + flow_weight · TVD(flows, target flows)."""
    got = shares(cohort)
    return (sum(tvd(got[k], want) for k, want in target.items())
            + flow_weight * tvd(flows(cohort), target_flows))


@dataclass(frozen=True)
class Generation:
    """What one generation found."""

    index: int  # 1-based
    best: float  # the generation's best score
    best_so_far: float


def minimise(
    evaluate: Callable[[list[np.ndarray]], list[float]],
    x0: np.ndarray,
    generations: int,
    popsize: int,
    sigma0: float = SIGMA0,
    seed: int = 1,
    on_generation: Callable[[Generation], None] | None = None,
) -> tuple[np.ndarray, float]:
    """CMA-ES in [0, 1]^k from x0 for `generations` generations; the best point and its score.

    `evaluate` scores a whole generation at once (in parallel, if it likes); x0 is the first
    candidate of the first generation.
    """
    es = cma.CMAEvolutionStrategy(
        np.asarray(x0, dtype=float), sigma0,
        {"bounds": [0.0, 1.0], "popsize": popsize, "seed": seed % (2**32 - 1) + 1,
         "verbose": -9, "verb_log": 0, "verb_disp": 0},
    )
    # The boundary transform maps what CMA-ES samples into the box; injecting x0's preimage makes
    # the first candidate x0 itself (a point near a bound would otherwise be moved).
    es.inject([es.boundary_handler.inverse(np.asarray(x0, dtype=float))], force=True)
    best_x, best_f = np.asarray(x0, dtype=float), math.inf
    for g in range(1, generations + 1):
        candidates = [np.asarray(x, dtype=float) for x in es.ask()]
        scores = [float(s) for s in evaluate(candidates)]
        es.tell(candidates, scores)
        i = int(np.argmin(scores))
        if scores[i] < best_f:
            best_x, best_f = candidates[i], scores[i]
        if on_generation:
            on_generation(Generation(g, scores[i], best_f))
    return best_x, best_f


@dataclass(frozen=True)
class CohortObjective:
    """Scores a generation of trait vectors on the same participants, in parallel on an engine."""

    engine: Engine
    cfg: NodConfig
    target: Shares
    target_flows: Flows
    n: int  # participants per candidate
    seed: int  # the first participant's seed
    traits: tuple[Trait, ...] = TRAITS
    flow_weight: float = FLOW_WEIGHT

    def cohorts(self, candidates: Sequence[np.ndarray]) -> list[list[Outcomes]]:
        """Each candidate's cohort (the same seeds for all), computed in one batch."""
        cfgs = [with_traits(self.cfg, from_unit(x, self.traits)) for x in candidates]
        jobs = [(cfg, self.seed + i) for cfg in cfgs for i in range(self.n)]
        done = self.engine.map(session_outcomes, jobs)
        return [done[k * self.n : (k + 1) * self.n] for k in range(len(cfgs))]

    def __call__(self, candidates: list[np.ndarray]) -> list[float]:
        """Each candidate's score."""
        return [
            score(c, self.target, self.target_flows, self.flow_weight)
            for c in self.cohorts(candidates)
        ]
