"""A simulated cohort's outcomes, computed on the engine, and their distance to the paper.

Participant i of a cohort is the offline session (`services.model.closed_loop`, cohort mode:
traits drawn around the configured ones from the seed) with seed `seed + i`; its outcomes are a
list of 8 (None: a timeout). Fitting and power need only these; `nod cohort` stores whole
sessions itself. Shares are per trial over CATEGORIES (a timeout is "none", whose paper share is
0); flows are Fig 8b's control → experiment categories (`services.model.phases`). Distances are
total-variation distances (TVD): half the L1 distance between two distributions.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from services.compute.engine import Engine
from services.model.closed_loop import run_offline_session
from services.model.outcome import OUTCOMES
from services.model.params import NodConfig
from services.model.phases import CONTROL_TRIALS, EXPERIMENT_TRIALS, phase_category

CATEGORIES: tuple[str, ...] = (*OUTCOMES, "none")
Outcomes = list[str | None]  # one participant's outcome per trial
Shares = dict[int, dict[str, float]]  # trial → category → share
Flows = dict[tuple[str, str], float]  # (control category, experiment category) → share


def session_outcomes(job: tuple[NodConfig, int]) -> Outcomes:
    """One simulated participant's outcomes (a task on the engine)."""
    cfg, seed = job
    return [t.outcome for t in run_offline_session(cfg, seed, cohort=True)]


def cohort_outcomes(engine: Engine, cfg: NodConfig, seed: int, n: int) -> list[Outcomes]:
    """The outcomes of participants seed..seed+n-1, in seed order."""
    return engine.map(session_outcomes, [(cfg, seed + i) for i in range(n)])


def shares(cohort: Sequence[Outcomes]) -> Shares:
    """Per-trial shares of each category over a cohort's outcomes (one list per participant)."""
    out: Shares = {}
    n = len(cohort)
    for k in range(len(cohort[0])):
        counts = dict.fromkeys(CATEGORIES, 0)
        for person in cohort:
            counts[person[k] or "none"] += 1
        out[k + 1] = {c: counts[c] / n for c in CATEGORIES}
    return out


def flows(cohort: Sequence[Outcomes]) -> Flows:
    """Fig 8b: the share of participants in each (control, experiment) category pair."""
    out: Flows = {(a, b): 0.0 for a in CATEGORIES for b in CATEGORIES}
    for person in cohort:
        control = phase_category([person[t - 1] for t in CONTROL_TRIALS]) or "none"
        experiment = phase_category([person[t - 1] for t in EXPERIMENT_TRIALS]) or "none"
        out[control, experiment] += 1 / len(cohort)
    return out


def tvd(a: dict[Any, float], b: dict[Any, float]) -> float:
    """Total-variation distance between two distributions (a key missing from one is 0 there)."""
    return 0.5 * sum(abs(a.get(k, 0.0) - b.get(k, 0.0)) for k in set(a) | set(b))


def load_shares(text: str, where: str) -> Shares:
    """Per-trial target shares from JSON ({"trials": {"1": {"C": .., ...}, ...}})."""
    try:
        doc = json.loads(text)
        trials = {int(k): {c: float(v.get(c, 0.0)) for c in CATEGORIES}
                  for k, v in doc["trials"].items()}
    except (ValueError, KeyError, AttributeError, TypeError) as exc:
        raise ValueError(f"{where}: not a table of per-trial outcome shares ({exc})") from None
    for trial, row in trials.items():
        total = sum(row.values())
        if not 0.98 <= total <= 1.02:
            raise ValueError(f"{where}: trial {trial} shares add up to {total:.3f}, not 1")
    return trials


def load_flows(text: str, where: str) -> Flows:
    """Fig 8b's flows from JSON ({"flows": {"C": {"C": count, ...}, ...}}), as shares."""
    try:
        doc = json.loads(text)
        counts = {(a, b): float(n) for a, row in doc["flows"].items() for b, n in row.items()}
    except (ValueError, KeyError, AttributeError, TypeError) as exc:
        raise ValueError(f"{where}: not a table of control → experiment flows ({exc})") from None
    unknown = {c for pair in counts for c in pair} - set(CATEGORIES)
    total = sum(counts.values())
    if unknown or total <= 0 or min(counts.values()) < 0:
        raise ValueError(f"{where}: flows need counts ≥ 0 between {', '.join(OUTCOMES)}")
    return {pair: n / total for pair, n in counts.items()}
