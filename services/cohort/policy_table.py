"""The adaptive policy's table: simulated people's outcomes per candidate setting and kind.

For each candidate setting, `people` simulated people (seeds `seed`, `seed + 1`, …, drawn like
a cohort's from the configuration) each play one session with that setting in every consensus
trial and the paper's settings in the control trials (an `AdaptivePolicy` of one candidate),
and each trial's outcome is counted under (its settings, its index) and the person's kind
(`closed_loop.person_kind`). The result is a `policy.OutcomeTable`, small (candidates × 8
trials × 4 kinds) and saved as JSON, so one build serves a whole cohort.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass

from services.model.closed_loop import person_kind, run_offline_session
from services.model.params import NodConfig
from services.model.policy import (
    KINDS,
    OUTCOMES,
    AdaptivePolicy,
    Counts,
    Kind,
    OutcomeTable,
    PolicySettings,
    TableKey,
)

Mapper = Callable[[Callable[["TableJob"], "TableRow"], Sequence["TableJob"]], Iterable["TableRow"]]


@dataclass(frozen=True)
class TableJob:
    """One simulated person of the table."""

    cfg: NodConfig
    seed: int
    candidate: PolicySettings


@dataclass(frozen=True)
class TableRow:
    """One simulated person: their kind, each trial's (settings, index, label, C on O)."""

    kind: Kind
    trials: tuple[tuple[PolicySettings, int, str, bool], ...]


def simulate_person(job: TableJob) -> TableRow:
    """One table session (a task on the engine)."""
    policy = AdaptivePolicy(OutcomeTable((job.candidate,), {}))
    trials = run_offline_session(job.cfg, job.seed, cohort=True, policy=policy)
    rows = []
    for t in trials:
        assert t.settings is not None  # set for every trial under a policy
        label = t.outcome if t.outcome in OUTCOMES else "none"
        rows.append((t.settings, t.trial, label,
                     t.outcome == "C" and t.option is not None and t.human == t.option))
    return TableRow(person_kind(job.cfg, job.seed), tuple(rows))


def build_table(
    cfg: NodConfig,
    candidates: Sequence[PolicySettings],
    people: int,
    seed: int,
    mapper: Mapper | None = None,
) -> OutcomeTable:
    """Simulate `people` per candidate (seeds from `seed`) and count their outcomes."""
    jobs = [TableJob(cfg, seed + i, c) for c in candidates for i in range(people)]
    results: Iterable[TableRow] = (mapper or _serial)(simulate_person, jobs)
    prior: Counter[Kind] = Counter()
    outcomes: dict[TableKey, dict[Kind, list[int]]] = {}
    for n, row in enumerate(results):
        if n < people:  # the same people under every candidate: count each kind once
            prior[row.kind] += 1
        for settings, trial, label, c_on_o in row.trials:
            cell = outcomes.setdefault((settings, trial), {}).setdefault(
                row.kind, [0] * (len(OUTCOMES) + 1))
            cell[OUTCOMES.index(label)] += 1
            cell[-1] += int(c_on_o)
    cells = {key: {k: Counts(tuple(v[:-1]), v[-1]) for k, v in by_kind.items()}
             for key, by_kind in outcomes.items()}
    return OutcomeTable(tuple(candidates), {k: prior[k] for k in KINDS}, cells)


def _serial(fn: Callable[[TableJob], TableRow], jobs: Sequence[TableJob]) -> Iterator[TableRow]:
    return map(fn, jobs)


def table_to_json(table: OutcomeTable) -> str:
    """The table as JSON (`table_from_json` reads it back exactly)."""
    return json.dumps({
        "candidates": [asdict(c) for c in table.candidates],
        "prior": dict(table.prior),
        "cells": [{"settings": asdict(s), "trial": t,
                   "kinds": {k: {"outcomes": list(c.outcomes), "c_on_o": c.c_on_o}
                             for k, c in by_kind.items()}}
                  for (s, t), by_kind in table.cells.items()],
    })


def table_from_json(text: str) -> OutcomeTable:
    """A table saved by `table_to_json` (ValueError if it is not one)."""
    try:
        data = json.loads(text)
        cells = {(PolicySettings(**c["settings"]), int(c["trial"])):
                 {k: Counts(tuple(v["outcomes"]), int(v["c_on_o"])) for k, v in c["kinds"].items()}
                 for c in data["cells"]}
        return OutcomeTable(tuple(PolicySettings(**c) for c in data["candidates"]),
                            {k: int(v) for k, v in data["prior"].items()}, cells)
    except (KeyError, TypeError, json.JSONDecodeError) as exc:
        raise ValueError(f"not a policy table: {exc}") from None
