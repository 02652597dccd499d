"""`nod fit` and `nod fit recovery`, one function each (the parser is `services.fit.cli`)."""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from services.analysis.sessions import InclusionRule
from services.cohort.person import load_cohort_params
from services.compute.engine import engine_from_args
from services.core.config import params_hash
from services.fit.data import read_study
from services.fit.estimator import LEVEL, Estimates, ModelClassifier
from services.fit.pipeline import Prepared, predictive, prepare, prepare_by_length
from services.fit.prior import load_prior
from services.fit.report import (
    by_length_table,
    fit_document,
    fit_table,
    flag_rate,
    press_times,
    recovery_table,
)
from services.fit.simulate import (
    TABLE_SEED,
    Population,
    default_cache,
    load_population,
    reference_table,
    simulate,
    truth,
)
from services.model.recovery import (
    BOOTSTRAP_DRAWS,
    CI_LEVEL,
    Recovery,
    recovery_intervals,
)
from services.model.recovery import recovery as recover
from services.model.summaries import summarise
from services.store import Store
from services.store.fits import FitRecord, write_fits


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _cache(args: argparse.Namespace) -> Path | None:
    return None if args.no_cache else (args.cache or default_cache())


def _population(args: argparse.Namespace) -> Population:
    """The fit's prior: `--prior` (the shipped stated prior, or "cohort") over `--params`."""
    return Population(load_cohort_params(args.params), load_prior(args.prior))


def _prepared(args: argparse.Namespace, pop: Population, run: Any, where: str) -> Prepared:
    t0 = time.monotonic()
    prep = prepare(pop, args.table, run, _cache(args))
    how = "from the cache" if prep.cached else f"simulated on {where}"
    trained = "trained" if prep.trained else "from the cache"
    _say(f"reference table: {args.table} simulated people {how}; estimator {trained} "
         f"({time.monotonic() - t0:.0f} s)")
    return prep


def method(pop: Population, k: int) -> str:
    """The fit's method, as stored with each estimate."""
    prior = "the calibrated cohort" if pop.prior.is_cohort else (
        f"{pop.prior.source} ({pop.prior.digest()})")
    return (f"sbi quantile-boosting CQR, table K={k}, prior {prior} over params "
            f"{params_hash(pop.cfg)}")


def fit(args: argparse.Namespace) -> int:
    """`nod fit`: every participant (or one), table / JSON, figures, stored in the database."""
    pop = _population(args)
    study = read_study(args.db, args.participant, InclusionRule(args.min_trials),
                       args.include_withdrawn)
    people, skipped = study.people, study.skipped
    for line in study.notes:
        _say(f"nod fit: {line}")
    for line in skipped:
        _say(f"nod fit: skipped: {line}")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    with engine_from_args(args) as engine:
        prep = _prepared(args, pop, engine.map, engine.where)
        summaries = np.stack([summarise(p.paths, p.layout) for p in people])
        estimates = prep.estimator.predict(summaries)
        sims = predictive(pop, prep, estimates, args.predictive, engine.map)
    observed = [press_times(s) for s in summaries]
    doc = fit_document(people, estimates, prep.estimator.check, sims, observed, {
        "method": method(pop, args.table), "seconds": round(time.monotonic() - t0, 1),
        "skipped": skipped, "left_out": study.notes,
    }, prior_p=prep.prior_check.p_value(summaries).tolist())
    if not args.no_store:
        _store(args.db, doc)
    if args.out is not None:
        from services.fit.figures import write_figures

        (args.out / "fit.json").write_text(json.dumps(doc, indent=2) + "\n")
        _write_csv(args.out / "fit.csv", doc)
        written = write_figures(doc, args.out)
        _say(f"wrote fit.json, fit.csv, {', '.join(p.name for p in written)} to {args.out}")
    print(json.dumps(doc, indent=2) if args.json else fit_table(doc))
    return 0


Row = tuple[str, str, str, float, float, float, float | None, float | None]


def _rows(doc: dict[str, Any]) -> list[Row]:
    """Each stored row: participant, session, parameter, estimate, low, high, probability, prior_p.

    probability None: not a 0/1 parameter; prior_p: the person's out-of-prior p-value.
    """
    return [
        (r["participant"], r["session"], name, v["estimate"], v["low"], v["high"],
         v.get("probability"), r.get("prior_check", {}).get("p"))
        for r in doc["participants"] for name, v in r["parameters"].items()
    ]


def _store(db: Path, doc: dict[str, Any]) -> None:
    now = time.time_ns()
    store = Store(db)
    try:
        write_fits(store, [FitRecord(*row[:6], LEVEL, doc["method"], now, row[6], row[7])
                           for row in _rows(doc)])
    finally:
        store.close()


def _write_csv(path: Path, doc: dict[str, Any]) -> None:
    """fit.csv, with fits.csv's columns; a parameter that is not 0/1 has probability NA."""
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(["participant", "session", "parameter", "estimate", "low", "high",
                         "probability", "prior_p"])
        writer.writerows((*row[:6], *("NA" if v is None else v for v in row[6:]))
                         for row in _rows(doc))


def recovery(args: argparse.Namespace) -> int:
    """`nod fit recovery`: planted people fitted as `nod fit` fits, and the gaze-model check."""
    pop = _population(args)
    planted = load_population(args.population) if args.population is not None else pop
    if args.by_length:
        return _recovery_by_length(args, pop, planted)
    n = args.participants
    with engine_from_args(args) as engine:
        prep = _prepared(args, pop, engine.map, engine.where)
        t0 = time.monotonic()
        # Another population's people carry the fit's parameters: truth in the fit's names.
        people = engine.map(simulate, [(planted, args.seed + i) for i in range(n)])
        theta = np.stack([truth(*planted.person(args.seed + i), prep.table.names)
                          for i in range(n)])
        summaries = np.stack([p.summaries for p in people])
        fit = prep.estimator.predict(summaries)
        flagged = int(np.sum(prep.prior_check.outside(summaries)))
        checks = _checks(theta, fit, prep.estimator.log_scaled)
        model = _model_recovery(args, prep, pop.without_gaze(), people,
                                planted.without_gaze(), engine.map)
        versus = None
        if args.versus is not None:  # which description made a person: the prior's or this?
            other = load_population(args.versus)
            versus = _model_recovery(args, prep, other, people, other, engine.map)
            versus["versus"] = str(args.versus)
        _say(f"{n} planted people simulated and fitted, model check done "
             f"({time.monotonic() - t0:.0f} s)")
    # The bootstrap's rng is the run's seed: a reviewer's rerun gives the same intervals.
    spread = [recovery_intervals(c, theta[:, j], fit.graded[:, j], fit.low[:, j],
                                 fit.high[:, j], args.seed) for j, c in enumerate(checks)]
    doc = {"parameters": [c.as_dict() | u for c, u in zip(checks, spread, strict=True)],
           "model_recovery": model, "prior_check": flag_rate(flagged, n),
           **({"versus": versus} if versus is not None else {}),
           "participants": n, "seed": args.seed,
           "population": "the fit's prior" if args.population is None else str(args.population),
           "intervals": {"level": CI_LEVEL, "correlation": "percentile bootstrap, people "
                         f"resampled, {BOOTSTRAP_DRAWS} draws, rng seed {args.seed}",
                         "coverage": "Wilson score"},
           "method": method(pop, args.table)}
    print(json.dumps(doc, indent=2) if args.json else recovery_table(checks, model, spread,
                                                                     doc["prior_check"], versus))
    return 0


def _checks(theta: np.ndarray, fit: Estimates, logs: Sequence[bool]) -> list[Recovery]:
    """Each parameter's recovery: planted truth (people × parameters) against the fit."""
    return [recover(name, theta[:, j], fit.graded[:, j], fit.low[:, j], fit.high[:, j],
                    log=logs[j]) for j, name in enumerate(fit.names)]


def _recovery_by_length(args: argparse.Namespace, pop: Population, planted: Population
                        ) -> int:
    """`nod fit recovery --by-length`: the planted people fitted after 1, 2, … 8 trials."""
    n = args.participants
    with engine_from_args(args) as engine:
        t0 = time.monotonic()
        table, estimators, trained = prepare_by_length(pop, args.table, engine.map,
                                                       _cache(args))
        _say(f"reference table: {args.table} simulated people; estimators after 1-8 trials "
             f"{'trained' if trained else 'from the cache'} ({time.monotonic() - t0:.0f} s)")
        people = engine.map(simulate, [(planted, args.seed + i) for i in range(n)])
    theta = np.stack([truth(*planted.person(args.seed + i), table.names) for i in range(n)])
    summaries = np.stack([p.summaries for p in people])
    checks: dict[int, list[Recovery]] = {}
    widths: dict[int, list[float]] = {}
    for k, estimator in estimators.at.items():
        fit = estimators.predict(k, summaries)
        checks[k] = _checks(theta, fit, estimator.log_scaled)
        widths[k] = [float(np.mean(fit.high[:, j] - fit.low[:, j]))
                     for j in range(len(fit.names))]
    doc = {"lengths": [{"trials": k, "parameters": [
               c.as_dict() | {"mean_width": round(w, 4)}
               for c, w in zip(checks[k], widths[k], strict=True)]} for k in sorted(checks)],
           "participants": n, "seed": args.seed,
           "population": "the fit's prior" if args.population is None else str(args.population),
           "method": method(pop, args.table) + "; one estimator per session length k, trained "
           "on the table cut to its first k trials"}
    print(json.dumps(doc, indent=2) if args.json else by_length_table(checks))
    return 0


def _model_recovery(args: argparse.Namespace, prep: Prepared, trained: Population,
                    people: list[Any], tested: Population, run: Any) -> dict[str, Any]:
    """Model recovery: which description made a session, the prior's or `trained`'s.

    Trained on K/4 table sessions of each; tested on the planted people and as many of
    `tested` (the same seeds): the gaze check's other description is the same people without
    the gaze term. `first`/`second`: the share of each description's sessions told right.
    """
    k = max(100, args.table // 4)
    table, _ = reference_table(trained, k, run, _cache(args))
    clf = ModelClassifier().train(prep.table.summaries[:k], table.summaries)
    held_out = run(simulate, [(tested, args.seed + i) for i in range(len(people))])
    mine = np.stack([p.summaries for p in people])
    other = np.stack([p.summaries for p in held_out])
    return {"accuracy": round(clf.accuracy(mine, other), 4),
            "first": round(clf.accuracy(mine, other[:0]), 4),
            "second": round(clf.accuracy(mine[:0], other), 4),
            "sessions": 2 * len(people), "trained_on": 2 * k, "table_seed": TABLE_SEED}
