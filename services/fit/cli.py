"""`nod fit`: each participant's model parameters with 90 % intervals; `nod fit recovery`.

    nod fit --db STUDY.sqlite [--participant P] [--min-trials N] [--include-withdrawn]
            [--out DIR] [--json] [--prior FILE.toml|cohort]
    nod fit recovery --participants N --seed S [--population FILE.toml] [--json]
    nod fit recovery --by-length --participants N [--table K]   # after 1, 2, … 8 trials

Both train the same estimator on the same reference table (K simulated people of the prior —
the stated ranges of services/fit/prior.toml over the fitted cohort's person, or `--prior` —
cached on disk) and run their simulations on the compute engine (an embedded local
cluster, or `--scheduler tcp://…`). docs/fit.md has the method, the recovery table and how to
read the output. Bad input is one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from services.core.cli import SEED, Parser, fail, int_in

PROG = "nod fit"
K_DEFAULT = 2000  # reference-table people: docs/fit.md says why this many
K_BY_LENGTH = 500  # `recovery --by-length` trains 8 estimators: a table that takes minutes


def _common(p: argparse.ArgumentParser) -> None:
    from services.compute.engine import add_engine_args

    p.add_argument("--params", type=Path, default=None, metavar="FILE.toml",
                   help="cohort traits overriding the fitted ones (the prior; default: the "
                   "cohort fitted to the paper)")
    p.add_argument("--prior", default=None, metavar="FILE.toml|cohort",
                   help="what people may differ in: ranges of traits and odds of kinds "
                   "(default: the shipped services/fit/prior.toml; \"cohort\": the calibrated "
                   "cohort itself, the prior before it)")
    p.add_argument("--table", type=int_in(20, 10**6), default=None, metavar="K",
                   help=f"simulated people the estimator learns from ({K_DEFAULT}; "
                   f"{K_BY_LENGTH} with recovery --by-length)")
    p.add_argument("--cache", type=Path, default=None, metavar="DIR",
                   help="where reference tables are kept (default: $NOD_CACHE_DIR or "
                   "~/.cache/nod/fit)")
    p.add_argument("--no-cache", action="store_true", help="simulate the table afresh, keep none")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_engine_args(p)


def fit_parser() -> Parser:
    """The command line of `nod fit`."""
    p = Parser(prog=PROG, description="Fit each participant of a study: the simulated "
               "participant's parameters, estimate and 90 % interval, by simulation-based "
               "inference (docs/fit.md). `nod fit recovery --help`: the recovery study.")
    p.add_argument("--db", type=Path, required=True, help="the study's session database")
    p.add_argument("--participant", default=None, metavar="ID", help="fit only this one")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="write fit.json, fit.csv and the figures (fit_intervals, fit_predictive)")
    p.add_argument("--predictive", type=int_in(0, 1000), default=10, metavar="N",
                   help="sessions simulated per participant for the predictive check (10; 0: "
                   "none)")
    p.add_argument("--no-store", action="store_true",
                   help="do not write the fit into the database (table fits)")
    p.add_argument("--min-trials", type=int_in(1, 10_000), default=None, metavar="N",
                   help="fit any session with at least N scored trials (default: complete "
                   "sessions only, the inclusion rule of `nod analyze study`)")
    p.add_argument("--include-withdrawn", action="store_true",
                   help="fit participants who withdrew too (default: left out, named in one "
                   "line)")
    _common(p)
    return p


def recovery_parser() -> Parser:
    """The command line of `nod fit recovery`."""
    p = Parser(prog=f"{PROG} recovery", description="Parameter recovery: simulate N people "
               "of the prior (or of --population) with known parameters, fit them as `nod fit` "
               "does, and "
               "report per parameter the correlation of true and estimated (with a 95 % "
               "bootstrap interval over the people, seeded by --seed), the bias and the "
               "coverage of the 90 % intervals (with its 95 % Wilson interval); how many the "
               "out-of-prior check flags; and whether "
               "sessions with and without the gaze term are told apart.")
    p.add_argument("--participants", type=int_in(2, 10**5), required=True, metavar="N")
    p.add_argument("--seed", type=SEED, default=1, help="person i has seed S + i (as nod cohort)")
    p.add_argument("--versus", type=Path, default=None, metavar="FILE.toml",
                   help="model recovery against another description of people (a population "
                   "file as --population's): how often a session's description, the prior's "
                   "or this one, is told right")
    p.add_argument("--population", type=Path, default=None, metavar="FILE.toml",
                   help="plant people of another population: a --params file (people drawn "
                   "around its traits, as nod cohort) or one that also states [traits.NAME] "
                   "ranges and [kinds] (drawn from them); default: the fit's prior")
    p.add_argument("--by-length", action="store_true",
                   help="r and coverage of each parameter after 1, 2, … 8 trials (the "
                   "estimators of partial sessions; no model-recovery check)")
    _common(p)
    return p


def main(argv: list[str] | None = None) -> int:
    """Run `nod fit …`; 2 for bad input."""
    args_in = list(sys.argv[1:] if argv is None else argv)
    from services.fit import commands
    from services.fit.data import FitInputError

    recovery = bool(args_in) and args_in[0] == "recovery"
    parser = recovery_parser() if recovery else fit_parser()
    args = parser.parse_args(args_in[1:] if recovery else args_in)
    if args.table is None:
        args.table = K_BY_LENGTH if getattr(args, "by_length", False) else K_DEFAULT
    from services.compute.engine import EngineError
    from services.core.config import ConfigError

    try:
        return commands.recovery(args) if recovery else commands.fit(args)
    except (FitInputError, ConfigError, EngineError, ValueError, OSError) as exc:
        return fail(parser.prog, f"error: {exc}")


if __name__ == "__main__":
    raise SystemExit(main())
