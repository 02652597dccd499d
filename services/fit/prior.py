"""The fit's prior: what people could plausibly differ in, as stated ranges (data, not code).

The estimator learns whatever the reference table's people differ in, and nothing else: a
trait the prior holds fixed cannot be recovered, however much 8 trials would tell of it. So the
prior is written down, wider than any one fitted population, in a TOML file (`prior.toml`
beside this module, its reasons in its comments and in docs/fit.md):

    [traits.preference_mean]          # any float trait of `ParticipantParams`
    low = 0.5
    high = 6.0
    scale = "linear"                  # uniform on [low, high]; "log": uniform on its log

    [kinds]                           # each kind of person, the probability of being one
    late_switcher = 0.5
    contrarian = 0.5
    firm_contrarian = 0.5             # among contrarians
    persistent_contrarian = 0.5       # among contrarians

A person of the prior is the cohort's person (`--params`: every trait not named here, the
population's constants such as `preference_sd` or `trust_step`) with the named traits drawn
from their ranges and each stated kind drawn 0/1 (`person_params`: the kind's share set to 0 or
1, so the `Participant` is of that kind for sure; a kind not stated keeps the cohort's share).
The calibrated cohort is one population inside the prior when its people's traits lie within
the ranges (`contains`, tested for the shipped cohort). `COHORT` is the other prior: the
calibrated cohort itself (`participant.jittered`), the fit's prior before this file.

Pure: a seeded numpy Generator in, traits out.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np

from services.core.config import ConfigError, load_toml
from services.model.participant import ParticipantParams

STRATEGIST = "late_switcher"
CONTRARIAN = "contrarian"
FIRM = "firm_contrarian"
PERSISTENT = "persistent_contrarian"
# Each kind of person and the share of the cohort's traits that makes it: a person config with
# the share 1 makes someone of that kind for sure, 0 no one (posterior draws, prior people).
KINDS: tuple[tuple[str, str], ...] = (
    (STRATEGIST, "late_switch_share"), (CONTRARIAN, "contrarian_share"), (FIRM, "contrarian_firm"),
    (PERSISTENT, "contrarian_persist"),
)
SHARE_OF = dict(KINDS)
KINDS_OF_CONTRARIAN = (FIRM, PERSISTENT)  # only where there are contrarians at all
DERIVED = ("gaze_use",)  # gaze_gain × trust0, where both vary

SHIPPED = resources.files("services.fit") / "prior.toml"
COHORT_NAME = "cohort"  # `--prior cohort`: the calibrated cohort itself


@dataclass(frozen=True, slots=True)
class Range:
    """One trait's range in the prior: uniform on [low, high], or on its log."""

    name: str
    low: float
    high: float
    scale: Literal["linear", "log"] = "linear"

    def draw(self, rng: np.random.Generator) -> float:
        """One person's value."""
        if self.scale == "log":
            return float(math.exp(rng.uniform(math.log(self.low), math.log(self.high))))
        return float(rng.uniform(self.low, self.high))


@dataclass(frozen=True, slots=True)
class Prior:
    """Stated ranges of traits and probabilities of kinds; empty: the calibrated cohort."""

    ranges: tuple[Range, ...] = ()
    kinds: tuple[tuple[str, float], ...] = ()
    source: str = COHORT_NAME

    @property
    def is_cohort(self) -> bool:
        """The calibrated cohort's own population (`participant.jittered`), not stated ranges."""
        return not self.ranges and not self.kinds

    def digest(self) -> str:
        """What the prior draws (not where it was read from): a reference table's cache key."""
        text = json.dumps([[dataclasses.astuple(r) for r in self.ranges], list(self.kinds)])
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def names(self, base: ParticipantParams) -> tuple[str, ...]:
        """The parameters a fit over this prior (over `base`) estimates, in output order.

        The traits that vary (high > low), then gaze_use where gaze_gain and trust0 both vary,
        then every kind one can be or not be: its probability strictly between 0 and 1 — the
        prior's, or for a kind it does not state the share `base` gives (a kind of contrarian
        only where there are contrarians).
        """
        traits = [r.name for r in self.ranges if r.high > r.low]
        extra = [d for d in DERIVED if {"gaze_gain", "trust0"} <= set(traits)]
        odds = self.odds(base)
        for kind, _ in KINDS:
            if 0 < odds[kind] < 1 and (kind not in KINDS_OF_CONTRARIAN or odds[CONTRARIAN] > 0):
                extra.append(kind)
        return (*traits, *extra)

    def odds(self, base: ParticipantParams) -> dict[str, float]:
        """Each kind's probability: the prior's, or the share `base` gives one it leaves."""
        return {kind: float(getattr(base, share)) for kind, share in KINDS} | dict(self.kinds)

    def draw(self, base: ParticipantParams, rng: np.random.Generator) -> ParticipantParams:
        """One person's traits: `base` with each range's trait drawn and each stated kind 0/1.

        Every range and every stated kind takes its draw whatever the others gave: person i of
        two priors that differ in one range differ in that trait only. A kind the prior does
        not state keeps `base`'s share, drawn by the `Participant` as in the cohort.
        """
        traits = {r.name: r.draw(rng) for r in self.ranges}
        kinds = {kind: bool(rng.random() < p) for kind, p in self.kinds}
        return person_params(base, traits, kinds)

    def contains(self, params: ParticipantParams, kinds: Mapping[str, bool]) -> bool:
        """Whether a person lies inside the prior.

        Every ranged trait within its range, and no kind the prior rules out (probability 0)
        or makes certain (1) otherwise.
        """
        for r in self.ranges:
            if not r.low <= getattr(params, r.name) <= r.high:
                return False
        odds = dict(self.kinds)
        return all(
            not (odds.get(kind, 0.0) == 0 and kinds.get(kind, False))
            and not (odds.get(kind, 0.0) == 1 and not kinds.get(kind, False))
            for kind, _ in KINDS if kind in odds
        )


COHORT = Prior()


def person_params(base: ParticipantParams, traits: Mapping[str, float],
                  kinds: Mapping[str, bool]) -> ParticipantParams:
    """`base` with these traits, and a person of each of these kinds for sure (or not at all)."""
    changes: dict[str, Any] = {**traits, **{SHARE_OF[k]: float(v) for k, v in kinds.items()}}
    return dataclasses.replace(base, **changes)


_FLOATS = {f.name for f in dataclasses.fields(ParticipantParams) if f.type in ("float", float)}


def prior_from_mapping(data: Mapping[str, Any], source: str) -> Prior:
    """A prior from its TOML tables (`[traits.NAME]` low/high/scale, `[kinds]`); checked."""
    unknown = set(data) - {"traits", "kinds"}
    if unknown:
        raise ConfigError(f"{source}: unknown table(s) {', '.join(sorted(unknown))} (a prior "
                          "has [traits.NAME] and [kinds])")
    traits, kinds = data.get("traits", {}), data.get("kinds", {})
    if not isinstance(traits, dict) or not isinstance(kinds, dict):
        raise ConfigError(f"{source}: traits and kinds must be tables")
    ranges = []
    for name, spec in traits.items():
        where = f"{source}: traits.{name}"
        if name not in _FLOATS:
            raise ConfigError(f"{where}: not a float trait of the participant")
        if not isinstance(spec, dict) or set(spec) - {"low", "high", "scale"}:
            raise ConfigError(f"{where}: expected a table of low, high and scale")
        try:
            low, high = float(spec["low"]), float(spec["high"])
        except (KeyError, TypeError, ValueError):
            raise ConfigError(f"{where}: low and high must be numbers") from None
        scale = spec.get("scale", "linear")
        if scale not in ("linear", "log"):
            raise ConfigError(f"{where}: scale must be \"linear\" or \"log\", not {scale!r}")
        if not (math.isfinite(low) and math.isfinite(high) and low <= high):
            raise ConfigError(f"{where}: needs finite low <= high")
        if scale == "log" and low <= 0:
            raise ConfigError(f"{where}: a log scale needs low > 0")
        ranges.append(Range(name, low, high, scale))
    odds = []
    for kind, p in kinds.items():
        if kind not in SHARE_OF:
            raise ConfigError(f"{source}: kinds.{kind}: not a kind ({', '.join(SHARE_OF)})")
        if not isinstance(p, int | float) or not 0 <= p <= 1:
            raise ConfigError(f"{source}: kinds.{kind}: a probability in [0, 1]")
        odds.append((kind, float(p)))
    prior = Prior(tuple(ranges), tuple(odds), source)
    if prior.is_cohort:
        raise ConfigError(f"{source}: states no trait and no kind (`--prior cohort` is the "
                          "calibrated cohort)")
    return prior


def load_prior(path: str | Path | None) -> Prior:
    """The shipped prior (None), the calibrated cohort ("cohort"), or a prior file."""
    if path is not None and str(path) == COHORT_NAME:
        return COHORT
    if path is None:
        import tomllib

        return prior_from_mapping(tomllib.loads(SHIPPED.read_text()), "the shipped prior.toml")
    return prior_from_mapping(load_toml(path), str(path))
