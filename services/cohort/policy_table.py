"""The adaptive policy's table: simulated people's outcomes per cell and kind of person.

`people` simulated people (seeds `seed`, `seed + 1`, …, drawn like a cohort's from the
configuration) each play one session in which every consensus trial draws one of the
candidate settings at random (`policy.ExplorePolicy`; the paper's settings in the control
trials), and each trial's outcome is counted under its cell — (its settings, its index, the
consensus trials before it with a gaze cue) — and the person's kind
(`closed_loop.person_kind`). The result is a `policy.OutcomeTable`, small (candidates × 8
trials × cues × 4 kinds) and saved as JSON, so one build serves a whole cohort.
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
    Counts,
    ExplorePolicy,
    Kind,
    OutcomeTable,
    PolicyRun,
    PolicySettings,
    TableKey,
    cued_before,
)

Mapper = Callable[[Callable[["TableJob"], "TableRow"], Sequence["TableJob"]], Iterable["TableRow"]]


@dataclass(frozen=True)
class TableJob:
    """One simulated person of the table."""

    cfg: NodConfig
    seed: int
    candidates: tuple[PolicySettings, ...]


@dataclass(frozen=True)
class TableRow:
    """One simulated person: their kind and each trial's (cell, label, C on O, C/CH on O)."""

    kind: Kind
    trials: tuple[tuple[TableKey, str, bool, bool], ...]


def simulate_person(job: TableJob) -> TableRow:
    """One table session (a task on the engine)."""
    run = PolicyRun(ExplorePolicy(job.candidates, job.seed), job.cfg.policy)
    run_offline_session(job.cfg, job.seed, cohort=True, policy=run)
    rows = []
    for p in run.history:
        rows.append(((p.settings, p.trial, cued_before(run.history, p.trial)), p.label,
                     p.on_option and p.outcome == "C",
                     p.on_option and p.outcome in ("C", "CH")))
    return TableRow(person_kind(job.cfg, job.seed), tuple(rows))


def build_table(
    cfg: NodConfig,
    candidates: Sequence[PolicySettings],
    people: int,
    seed: int,
    mapper: Mapper | None = None,
) -> OutcomeTable:
    """Simulate `people` (seeds from `seed`) exploring the candidates; count their outcomes."""
    jobs = [TableJob(cfg, seed + i, tuple(candidates)) for i in range(people)]
    results: Iterable[TableRow] = (mapper or _serial)(simulate_person, jobs)
    prior: Counter[Kind] = Counter()
    outcomes: dict[TableKey, dict[Kind, list[int]]] = {}
    for row in results:
        prior[row.kind] += 1
        for key, label, c_on_o, agree in row.trials:
            cell = outcomes.setdefault(key, {}).setdefault(row.kind, [0] * (len(OUTCOMES) + 2))
            cell[OUTCOMES.index(label)] += 1
            cell[-2] += int(c_on_o)
            cell[-1] += int(agree)
    cells = {key: {k: Counts(tuple(v[:-2]), v[-2], v[-1]) for k, v in by_kind.items()}
             for key, by_kind in outcomes.items()}
    return OutcomeTable(tuple(candidates), {k: prior[k] for k in KINDS}, cells)


def _serial(fn: Callable[[TableJob], TableRow], jobs: Sequence[TableJob]) -> Iterator[TableRow]:
    return map(fn, jobs)


def table_to_json(table: OutcomeTable) -> str:
    """The table as JSON (`table_from_json` reads it back exactly)."""
    return json.dumps({
        "candidates": [asdict(c) for c in table.candidates],
        "prior": dict(table.prior),
        "cells": [{"settings": asdict(s), "trial": t, "cued": cued,
                   "kinds": {k: {"outcomes": list(c.outcomes), "c_on_o": c.c_on_o,
                                 "agree_on_o": c.agree_on_o} for k, c in by_kind.items()}}
                  for (s, t, cued), by_kind in table.cells.items()],
    })


def table_from_json(text: str) -> OutcomeTable:
    """A table saved by `table_to_json` (ValueError if it is not one)."""
    try:
        data = json.loads(text)
        cells = {(PolicySettings(**c["settings"]), int(c["trial"]), int(c["cued"])):
                 {k: Counts(tuple(v["outcomes"]), int(v["c_on_o"]), int(v["agree_on_o"]))
                  for k, v in c["kinds"].items()}
                 for c in data["cells"]}
        return OutcomeTable(tuple(PolicySettings(**c) for c in data["candidates"]),
                            {k: int(v) for k, v in data["prior"].items()}, cells)
    except (KeyError, TypeError, json.JSONDecodeError) as exc:
        raise ValueError(f"not a policy table: {exc}") from None
