"""Simulated people for the fit: the prior, one session's task, and the cached reference table.

A `Population` is who the simulated people are: the calibrated cohort's (`prior.COHORT`: person
`seed` is exactly the participant `nod cohort` simulates with that seed,
`closed_loop.run_offline_session(cohort=True)`, traits drawn by `participant.jittered` around
the cohort's traits) or a stated prior's (`services/fit/prior.toml`: each named trait drawn
from its range and each kind 0/1 over the cohort's person, the session run of exactly that
person). The fit's prior is a population; so are the other people `nod fit recovery
--population` plants.

Under the cohort the parameters fitted are whichever traits `jittered` draws per person — found
by drawing, not listed here, so a trait added to the model is fitted without a change here —
plus the derived `gaze_use` (gaze_gain × trust0: the eyes' pull on the person at the first gaze
trial) and the person's kind, 0/1, wherever the cohort has such people: `late_switcher` (a
strategist, `late_switch_share` > 0), `contrarian` (`contrarian_share` > 0), `firm_contrarian`
(one who holds the other box, `contrarian_firm` > 0) and `persistent_contrarian` (one who never
comes round, `contrarian_persist` > 0). Under a stated prior they are the prior's
(`Prior.names`).

A session is one task on the engine (`services.compute.engine`); its result is small (traits,
summaries, outcomes, press times), so thousands travel back cheaply. The reference table (K
people) is cached on disk, keyed by the parameters, the prior, K, the summaries' names and the
source of the model and the summaries: another model never reuses a stale table.
"""

from __future__ import annotations

import ast
import dataclasses
import hashlib
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from services.cohort.person import cohort_params
from services.core.config import load_toml, params_hash
from services.fit.prior import (
    COHORT,
    CONTRARIAN,
    DERIVED,
    FIRM,
    KINDS,
    KINDS_OF_CONTRARIAN,
    PERSISTENT,
    STRATEGIST,
    Prior,
    prior_from_mapping,
)
from services.model.closed_loop import OfflineTrial, run_offline_session
from services.model.params import NodConfig
from services.model.participant import Participant, ParticipantParams, jittered
from services.model.summaries import from_offline, summarise, summary_names

TABLE_SEED = 10**9  # reference-table person i has seed TABLE_SEED + i: never a study's seed
PRIOR_STREAM = 35  # a prior person's traits come from rng([seed, PRIOR_STREAM]), not the session's

def drawn_traits(base: ParticipantParams) -> tuple[str, ...]:
    """The traits `jittered` draws per person (those that differ from `base` in some draw)."""
    rng = np.random.default_rng(0)
    draws = [jittered(base, rng) for _ in range(16)]
    names = []
    for f in dataclasses.fields(base):
        value = getattr(base, f.name)
        if isinstance(value, float) and any(getattr(d, f.name) != value for d in draws):
            names.append(f.name)
    return tuple(names)


def parameter_names(base: ParticipantParams) -> tuple[str, ...]:
    """Every parameter the fit estimates for this cohort, in output order."""
    names = drawn_traits(base)
    extra = [d for d in DERIVED if {"gaze_gain", "trust0"} <= set(names)]
    for kind, share in KINDS:
        if getattr(base, share) > 0 and (
            kind not in KINDS_OF_CONTRARIAN or base.contrarian_share > 0
        ):
            extra.append(kind)
    return (*names, *extra)


def true_person(cfg: NodConfig, seed: int) -> tuple[ParticipantParams, dict[str, bool]]:
    """Person `seed` of the cohort: its traits and its kinds (strategist, contrarian, ...).

    The same draws, in the same order, as `run_offline_session(cfg, seed, cohort=True)` makes
    (a test holds the two together).
    """
    rng = np.random.default_rng(seed)
    params = jittered(cfg.participant, rng)
    return params, kinds_of(params, cfg, int(rng.integers(2**31)))


def kinds_of(params: ParticipantParams, cfg: NodConfig, person_seed: int) -> dict[str, bool]:
    """The kinds the `Participant` of these traits and this seed is (it draws them itself)."""
    person = Participant(params, cfg.layout, seed=person_seed)
    return {STRATEGIST: person.strategist, CONTRARIAN: person.contrarian, FIRM: person.firm,
            PERSISTENT: person.persistent}


def truth(params: ParticipantParams, kinds: dict[str, bool], names: Sequence[str]) -> np.ndarray:
    """A person's parameter vector in `names` order."""
    values = []
    for n in names:
        if n == "gaze_use":
            values.append(params.gaze_gain * params.trust0)
        elif n in kinds:
            values.append(float(kinds[n]))
        else:
            values.append(float(getattr(params, n)))
    return np.asarray(values, dtype=float)


@dataclass(frozen=True, slots=True)
class Population:
    """Who the simulated people are: the cohort `cfg`'s, or `prior`'s drawn over it."""

    cfg: NodConfig
    prior: Prior = COHORT

    @property
    def names(self) -> tuple[str, ...]:
        """The parameters a fit over this population estimates, in output order."""
        if self.prior.is_cohort:
            return parameter_names(self.cfg.participant)
        return self.prior.names(self.cfg.participant)

    def person(self, seed: int) -> tuple[ParticipantParams, dict[str, bool]]:
        """Person `seed`: their traits and their kinds."""
        if self.prior.is_cohort:
            return true_person(self.cfg, seed)
        params = self.prior.draw(self.cfg.participant, np.random.default_rng([seed, PRIOR_STREAM]))
        # The session's own seed for the person, as `run_offline_session(cohort=False)` draws it.
        return params, kinds_of(params, self.cfg, int(np.random.default_rng(seed).integers(2**31)))

    def session(self, seed: int) -> list[OfflineTrial[Any]]:
        """Person `seed`'s session, recorded (`nod cohort`'s own under the cohort)."""
        if self.prior.is_cohort:
            return run_offline_session(self.cfg, seed, cohort=True, record=True)
        params = self.prior.draw(self.cfg.participant, np.random.default_rng([seed, PRIOR_STREAM]))
        return run_offline_session(dataclasses.replace(self.cfg, participant=params), seed,
                                   record=True)

    def without_gaze(self) -> Population:
        """The same people with the gaze term removed (nobody is pulled by the eyes)."""
        cfg = dataclasses.replace(
            self.cfg, participant=dataclasses.replace(self.cfg.participant, gaze_gain=0.0))
        ranges = tuple(r for r in self.prior.ranges if r.name != "gaze_gain")
        return Population(cfg, dataclasses.replace(self.prior, ranges=ranges))

    def key(self) -> str:
        """The cache key of this population's reference tables (any K: person i is the same)."""
        parts = [params_hash(self.cfg), str(TABLE_SEED), ",".join(summary_names()),
                 _source_digest()]
        if not self.prior.is_cohort:  # the cohort's key is the one it had before priors
            parts.append(self.prior.digest())
        return hashlib.sha256("|".join(parts).encode()).hexdigest()[:16]


def load_population(path: Path) -> Population:
    """Another population, from a TOML file: people `nod fit recovery --population` plants.

    Its `[participant]` (and other) tables are a `--params` file's: the cohort's traits over
    the fitted ones, people drawn around them by `participant.jittered` (the split person of
    docs/fit.md). A file that also states `[traits.NAME]` ranges or `[kinds]` (a prior's
    tables, `services/fit/prior.py`) draws its people from those instead.
    """
    data = load_toml(path)
    stated: dict[str, Any] = {k: data.pop(k) for k in ("traits", "kinds") if k in data}
    prior = prior_from_mapping(stated, str(path)) if stated else COHORT
    return Population(cohort_params(data, str(path)), prior)


@dataclass(frozen=True, slots=True)
class Simulated:
    """What one simulated session leaves for the fit."""

    seed: int
    theta: np.ndarray  # the person's parameters (`Population.names` order)
    summaries: np.ndarray  # `summary_names()` order
    outcomes: tuple[str | None, ...]  # per trial (None: a timeout)
    press_s: tuple[float | None, ...]  # per trial, from "go" (None: no press)


def _simulated(seed: int, theta: np.ndarray, trials: Sequence[OfflineTrial[Any]],
               cfg: NodConfig) -> Simulated:
    return Simulated(seed, theta, summarise(from_offline(trials), cfg.layout),
                     tuple(t.outcome for t in trials), tuple(t.press_s for t in trials))


def simulate(job: tuple[Population, int]) -> Simulated:
    """Person `seed` of the population, simulated (an engine task)."""
    pop, seed = job
    params, kinds = pop.person(seed)
    return _simulated(seed, truth(params, kinds, pop.names), pop.session(seed), pop.cfg)


def simulate_given(job: tuple[NodConfig, int]) -> Simulated:
    """A session of exactly `cfg.participant` (no person-to-person draw): predictive checks."""
    cfg, seed = job
    return _simulated(seed, np.zeros(0), run_offline_session(cfg, seed, record=True), cfg)


Mapper = Callable[[Callable[[Any], Simulated], list[Any]], list[Simulated]]


@dataclass(frozen=True, slots=True)
class Table:
    """K simulated people: parameters and summaries as arrays."""

    names: tuple[str, ...]
    theta: np.ndarray  # K × P
    summaries: np.ndarray  # K × F


def _model_sources() -> list[Path]:
    """The model modules a simulated session runs.

    The closed loop's and the summaries' imports, followed through `services.model` (found by
    reading the sources, not by importing them).
    """
    root = Path(__file__).resolve().parents[1] / "model"
    todo, seen = ["closed_loop", "summaries"], set()
    while todo:
        name = todo.pop()
        if name in seen or not (root / f"{name}.py").is_file():
            continue
        seen.add(name)
        tree = ast.parse((root / f"{name}.py").read_text())
        for node in ast.walk(tree):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.module == "services.model":
                todo += [alias.name for alias in node.names]
            elif (node.module or "").startswith("services.model."):
                todo.append(str(node.module).split(".")[2])
    return [root / f"{n}.py" for n in sorted(seen)]


def _source_digest() -> str:
    """The source a session's simulation and summaries run: other code makes another table."""
    digest = hashlib.sha256()
    for path in _model_sources():
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def default_cache() -> Path:
    """Where tables are kept: $NOD_CACHE_DIR, else $XDG_CACHE_HOME/nod/fit, else ~/.cache."""
    if os.environ.get("NOD_CACHE_DIR"):
        return Path(os.environ["NOD_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "nod" / "fit"


def _cached(cache: Path, key: str, names: tuple[str, ...]) -> Table | None:
    """The largest cached table of this key (its first K rows are the table of K people)."""
    best: Table | None = None
    for path in cache.glob(f"table-{key}-*.npz"):
        try:
            with np.load(path) as data:
                if tuple(str(n) for n in data["names"]) != names:
                    continue
                table = Table(names, data["theta"], data["summaries"])
        except (OSError, ValueError, KeyError):
            continue  # a torn or foreign file: simulate instead
        if best is None or len(table.theta) > len(best.theta):
            best = table
    return best


def reference_table(pop: Population, k: int, run: Mapper, cache: Path | None
                    ) -> tuple[Table, bool]:
    """K people of the population (the prior); (table, whether all came from the cache).

    Person i of every table is the same person (seed TABLE_SEED + i), so a cached table of more
    people serves a smaller one and a smaller one is extended, never simulated again.
    """
    names = pop.names
    key = pop.key()
    have = _cached(cache, key, names) if cache is not None else None
    done = 0 if have is None else min(k, len(have.theta))
    if have is not None and done == k:
        return Table(names, have.theta[:k], have.summaries[:k]), True
    sims = run(simulate, [(pop, TABLE_SEED + i) for i in range(done, k)])
    theta = np.stack([s.theta for s in sims])
    summaries = np.stack([s.summaries for s in sims])
    if have is not None:
        theta = np.concatenate([have.theta[:done], theta])
        summaries = np.concatenate([have.summaries[:done], summaries])
    table = Table(names, theta, summaries)
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        path = cache / f"table-{key}-{k}.npz"
        tmp = cache / f".table-{key}-{k}.tmp.npz"
        np.savez(tmp, names=np.array(names), theta=table.theta, summaries=table.summaries)
        tmp.replace(path)  # a table is whole or absent, never half written
    return table, False
