"""`nod calibrate-cohort`: fit the simulated participant's traits to the paper, then check the fit.

The target is the paper's Fig 8a (per-trial shares of C, CH, D, DH) and Fig 8b (control →
experiment flows), shipped in `services/cohort/paper/` (`--target`, `--flows` for others). The
search is CMA-ES over the traits of `services.sim.fit.TRAITS`, starting from the `--params`
person (by default the shipped fit), every candidate scored on the same `--participants`
(common random numbers), each generation computed in parallel on the engine (a local cluster,
or `--scheduler` for a lab's Dask cluster). It always ends with an honest check: the fitted
person on `--holdout` other people (≥ 400 by default, seeds disjoint from the fit's), printed
per trial and per flow next to the paper. `--out` writes the traits as a `--params` file that
says how it was made; `--evaluate` fits nothing and only checks.

Beside each distance stands what a study of the paper's size (`--study-size`, 51) drawn from the
model would show: `--studies` bootstrap studies of the held-out people give the 51-person noise
floor (the 95th percentile of a study's TVD to the model) and the probability that such a study
is at least as far from the model as the paper is. A distance below that floor is not evidence
of a better model: the paper itself could not tell it apart.

A cohort fitted to a table is a model of that table, not a replication of the study.
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, fields
from datetime import UTC, datetime
from importlib.abc import Traversable
from pathlib import Path

import numpy as np
import numpy.typing as npt

from services.cohort.outcomes import (
    CATEGORIES,
    Flows,
    Outcomes,
    Shares,
    cohort_outcomes,
    flows,
    load_flows,
    load_shares,
    shares,
    tvd,
)
from services.cohort.person import FIG8A, FIG8B, load_cohort_params
from services.compute.engine import (
    Engine,
    EngineError,
    add_engine_args,
    code_fingerprint,
    engine_from_args,
)
from services.core.cli import SEED, Parser, fail, int_in, positive_float
from services.model.outcome import OUTCOMES
from services.model.params import NodConfig, ParticipantParams
from services.model.phases import CONTROL_TRIALS, EXPERIMENT_TRIALS, phase_category
from services.sim.fit import (
    FLOW_WEIGHT,
    SIGMA0,
    TRAITS,
    CohortObjective,
    Generation,
    Trait,
    default_popsize,
    from_unit,
    minimise,
    to_unit,
    with_traits,
)

HOLDOUT_OFFSET = 10**6  # default held-out seeds: seed + 10⁶ on, never a fit seed
PAPER_N = 51  # the paper's participants (Fig 8b's counts add up to 51)
STUDIES = 2000  # bootstrap studies: the 95th percentile and a p of ≈ 0.05 to ± 0.005


@dataclass(frozen=True)
class Check:
    """A cohort next to the paper: its shares and flows, and their distances."""

    n: int
    seed: int
    shares: Shares
    flows: Flows
    trial_tvd: dict[int, float]
    flow_tvd: float

    def score(self, flow_weight: float) -> float:
        """The search's score of this cohort: Σ trial TVD + flow_weight × flow TVD."""
        return sum(self.trial_tvd.values()) + flow_weight * self.flow_tvd


def check(cohort: list[Outcomes], seed: int, target: Shares, target_flows: Flows) -> Check:
    """How far a cohort (participants seed..) is from the paper's tables."""
    got, moved = shares(cohort), flows(cohort)
    return Check(len(cohort), seed, got, moved,
                 {k: tvd(got[k], want) for k, want in target.items()}, tvd(moved, target_flows))


@dataclass(frozen=True)
class Noise:
    """How far studies of the paper's size drawn from the model land from the model.

    A TVD is never 0 for a finite study, so the paper's distance is read against these: the
    floor is the 95th percentile of a study's TVD to the model, p the share of studies at least
    as far from the model as the paper is (a parametric bootstrap: a small p says the paper is
    unlikely to be a study of this model; a distance below the floor is not evidence).
    """

    size: int
    studies: int
    seed: int
    trial_floor: dict[int, float]
    trial_p: dict[int, float]
    flow_floor: float
    flow_p: float


def _codes(cohort: Sequence[Outcomes]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Each person's category per trial, and their (control, experiment) flow, as indices."""
    index = {c: i for i, c in enumerate(CATEGORIES)}
    trials = np.array([[index[o or "none"] for o in person] for person in cohort], dtype=np.int64)
    pairs = np.array([index[phase_category([person[t - 1] for t in CONTROL_TRIALS]) or "none"]
                      * len(CATEGORIES)
                      + index[phase_category([person[t - 1] for t in EXPERIMENT_TRIALS]) or "none"]
                      for person in cohort], dtype=np.int64)
    return trials, pairs


def _study_tvd(codes: npt.NDArray[np.int64], draws: npt.NDArray[np.int64],
               bins: int) -> npt.NDArray[np.float64]:
    """Each drawn study's TVD to the whole cohort, over one categorical variable."""
    model = np.bincount(codes, minlength=bins) / len(codes)
    studies, size = draws.shape
    rows = np.arange(studies)[:, None] * bins + codes[draws]
    got = np.bincount(rows.ravel(), minlength=studies * bins).reshape(studies, bins) / size
    return np.asarray(0.5 * np.abs(got - model).sum(axis=1), dtype=np.float64)


def study_noise(cohort: Sequence[Outcomes], c: Check, size: int = PAPER_N,
                studies: int = STUDIES, seed: int = 1) -> Noise:
    """The paper's distances (in c, of this cohort) against studies of `size` from the cohort.

    The cohort is the model: each study resamples `size` of its people with replacement (seeded,
    so a report is reproducible) and is measured as the paper was, per trial and for the flows.
    """
    trials, pairs = _codes(cohort)
    draws = np.random.default_rng(seed).integers(0, len(cohort), (studies, size))
    bins = len(CATEGORIES)

    def floor_p(d: npt.NDArray[np.float64], paper: float) -> tuple[float, float]:
        # ≥ with a rounding slack: shares of 51 are multiples of 1/51, so ties are real
        return float(np.quantile(d, 0.95)), float(np.mean(d >= paper - 1e-9))

    per_trial = {k: floor_p(_study_tvd(trials[:, k - 1], draws, bins), c.trial_tvd[k])
                 for k in sorted(c.trial_tvd) if k <= trials.shape[1]}
    flow_floor, flow_p = floor_p(_study_tvd(pairs, draws, bins * bins), c.flow_tvd)
    return Noise(size, studies, seed, {k: v[0] for k, v in per_trial.items()},
                 {k: v[1] for k, v in per_trial.items()}, flow_floor, flow_p)


def trial_table(target: Shares, c: Check, noise: Noise | None = None) -> str:
    """Per trial: the paper's and the model's shares (%), their TVD, and the study noise."""
    head = "trial  paper C/CH/D/DH     model C/CH/D/DH/none    TVD"
    rows = [head + (f"    floor({noise.size})  p({noise.size})" if noise else "")]
    for k, want in sorted(target.items()):
        paper = "/".join(f"{want[o] * 100:.0f}" for o in OUTCOMES)
        model = "/".join(f"{c.shares[k][o] * 100:.0f}" for o in CATEGORIES)
        row = f"{k:>5}  {paper:<19} {model:<23} {c.trial_tvd[k]:.3f}"
        if noise is not None and k in noise.trial_p:
            row += f"    {noise.trial_floor[k]:9.3f}  {noise.trial_p[k]:5.3f}"
        rows.append(row)
    return "\n".join(rows)


def flow_table(target_flows: Flows, c: Check, noise: Noise | None = None) -> str:
    """Fig 8b: each control → experiment flow of the paper or the model (% of participants)."""
    rows = ["control → experiment   paper %   model %"]
    for (a, b) in sorted(set(target_flows) | set(c.flows),
                         key=lambda p: (CATEGORIES.index(p[0]), CATEGORIES.index(p[1]))):
        paper, model = target_flows.get((a, b), 0.0), c.flows.get((a, b), 0.0)
        if paper or model:
            rows.append(f"{a:>7} → {b:<12} {paper * 100:8.1f}  {model * 100:8.1f}")
    rows.append(f"TVD of the flows: {c.flow_tvd:.3f}" + (
        "" if noise is None else
        f" (floor({noise.size}) {noise.flow_floor:.3f}, p({noise.size}) {noise.flow_p:.3f})"))
    return "\n".join(rows)


def noise_note(noise: Noise) -> str:
    """What the floor and p columns are, and what a distance below the floor does not show."""
    return (f"floor({noise.size}): 95th percentile of the TVD to the model of {noise.studies} "
            f"studies of {noise.size} people drawn from the held-out people (seed {noise.seed}); "
            f"p({noise.size}): the share of them at least as far from the model as the paper "
            f"is. A distance below the floor is not evidence of a better model.")


def report(target: Shares, target_flows: Flows, c: Check, noise: Noise | None = None) -> str:
    """Both tables for one cohort, with their heading (and the study noise, if given)."""
    return (f"{c.n} participants (seeds {c.seed}..{c.seed + c.n - 1}) next to the paper:\n"
            f"{trial_table(target, c, noise)}\n{flow_table(target_flows, c, noise)}"
            + ("" if noise is None else "\n" + noise_note(noise)))


def write_params(path: Path, cfg: NodConfig, how: list[str]) -> None:
    """The fitted person as a `--params` file: every trait that differs from SPEC, and how."""
    spec = ParticipantParams()
    values = {f.name: getattr(cfg.participant, f.name) for f in fields(ParticipantParams)}
    keep = {k: v for k, v in values.items() if isinstance(v, int | float)
            and (k in {t.name for t in TRAITS} or v != getattr(spec, k))}
    lines = [f"# {line}" for line in how] + ["[participant]"]
    lines += [f"{k} = {v:.4f}" if isinstance(v, float) else f"{k} = {v}" for k, v in keep.items()]
    path.write_text("\n".join(lines) + "\n")


def against_start(fitted: Check, start: Check, flow_weight: float) -> list[str]:
    """The fitted person next to its start on the same held-out people, and which to keep.

    A fit scored on its own people can beat its start there and lose to it on others (too few
    people per candidate, too many traits, too large a first step): said, not hidden.
    """
    a, b = start.score(flow_weight), fitted.score(flow_weight)
    lines = [f"its start on the same people: Σ trial TVD {sum(start.trial_tvd.values()):.3f}, "
             f"flows {start.flow_tvd:.3f}; score {a:.3f} against the fit's {b:.3f} "
             f"(Σ trial TVD + {flow_weight:g} × flow TVD)"]
    if b > a:
        lines.append("the fit is WORSE than its start on people it was not fitted to: keep the "
                     "start, or refit with more --participants per candidate, fewer --traits or "
                     "a smaller --sigma0")
    return lines


def provenance(args: argparse.Namespace, where: str, best: float, c: Check,
               noise: Noise | None = None) -> list[str]:
    """How a fit was made, for the head of its file."""
    popsize = args.popsize or default_popsize(len(args.traits))
    held = " ".join(f"{c.trial_tvd[k]:.3f}" for k in sorted(c.trial_tvd))
    return [
        "A MODEL OF THE PAPER'S FIG 8a/8b, NOT A REPLICATION: participant traits that make the",
        "simulated cohort's outcomes resemble the paper's tables; nothing was measured on people.",
        f"made by: nod calibrate-cohort {shlex.join(args.argv)}",
        f"fitted {datetime.now(UTC):%Y-%m-%d %H:%M} UTC on {where}, nod-hri code "
        f"{code_fingerprint()}",
        f"CMA-ES (pycma): {args.generations} generations of {popsize} candidates, sigma0 "
        f"{args.sigma0} of each trait's range over {len(args.traits)} traits; "
        f"{args.participants} participants per candidate, "
        f"seeds {args.seed}..{args.seed + args.participants - 1} (common random numbers); "
        f"best score on them {best:.3f} (Σ trial TVD + {args.flow_weight:g} × flow TVD)",
        f"held out: {c.n} participants, seeds {c.seed}..{c.seed + c.n - 1}: TVD per trial "
        f"1-{len(c.trial_tvd)} = {held}; flows (Fig 8b) {c.flow_tvd:.3f}",
    ] + ([] if noise is None else [
        f"{noise.size}-person studies of them ({noise.studies} drawn, seed {noise.seed}): "
        "noise floor (95th percentile of a study's TVD to the model) per trial = "
        + " ".join(f"{noise.trial_floor[k]:.3f}" for k in sorted(noise.trial_floor))
        + f"; flows {noise.flow_floor:.3f}",
        "p (a study at least as far from the model as the paper) per trial = "
        + " ".join(f"{noise.trial_p[k]:.3f}" for k in sorted(noise.trial_p))
        + f"; flows {noise.flow_p:.3f}",
    ])


def trait_list(text: str) -> tuple[Trait, ...]:
    """`--traits a,b`: the named traits of TRAITS, in the order given."""
    by_name = {t.name: t for t in TRAITS}
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in by_name]
    if unknown or not names or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(
            f"{text!r}: name fitted traits once each, of: {', '.join(by_name)}")
    return tuple(by_name[n] for n in names)


def _read(source: Path | Traversable) -> str:
    return source.read_text()


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod calibrate-cohort`."""
    p = Parser(prog="nod calibrate-cohort", description=__doc__.splitlines()[0])
    p.add_argument("--target", type=Path, default=None,
                   help="per-trial shares (JSON; default: the paper's Fig 8a)")
    p.add_argument("--flows", type=Path, default=None,
                   help="control → experiment flows (JSON; default: the paper's Fig 8b)")
    p.add_argument("--out", type=Path, default=None, help="write the fitted traits here (TOML)")
    p.add_argument("--params", type=Path, default=None,
                   help="base parameters (TOML); its person is the search's start (default: the "
                   "shipped fit)")
    p.add_argument("--participants", type=int_in(2, 10**5), default=60,
                   help="cohort size per candidate (60)")
    p.add_argument("--seed", type=SEED, default=1, help="first seed of the fit's cohort (1)")
    p.add_argument("--generations", type=int_in(1, 10**4), default=14,
                   help="CMA-ES generations (14)")
    p.add_argument("--popsize", type=int_in(2, 1000), default=None,
                   help=f"candidates per generation (pycma's default: "
                   f"{default_popsize(len(TRAITS))})")
    p.add_argument("--sigma0", type=positive_float, default=SIGMA0,
                   help=f"first step, share of each trait's range ({SIGMA0})")
    p.add_argument("--flow-weight", type=positive_float, default=FLOW_WEIGHT,
                   help=f"weight of the Fig 8b flows' TVD in the score, against the sum of the "
                   f"trials' ({FLOW_WEIGHT:g})")
    p.add_argument("--holdout", type=int_in(1, 10**6), default=400,
                   help="participants of the check (400)")
    p.add_argument("--holdout-seed", type=SEED, default=None,
                   help=f"their first seed (default: --seed + {HOLDOUT_OFFSET})")
    p.add_argument("--traits", type=trait_list, default=TRAITS, metavar="NAME,NAME",
                   help="fit only these traits, the others held at the --params person's "
                   "(default: all of " + ", ".join(t.name for t in TRAITS) + ")")
    p.add_argument("--evaluate", action="store_true",
                   help="fit nothing: check the --params (or shipped) person on the held-out "
                   "people")
    p.add_argument("--studies", type=int_in(1, 10**6), default=STUDIES,
                   help=f"bootstrap studies of the held-out people for the noise floor and p "
                   f"({STUDIES}; seeded by --seed)")
    p.add_argument("--study-size", type=int_in(1, 10**5), default=PAPER_N,
                   help=f"people per bootstrap study: the paper's ({PAPER_N})")
    add_engine_args(p)
    return p


def fit(engine: Engine, cfg: NodConfig, target: Shares, target_flows: Flows,
        args: argparse.Namespace) -> tuple[NodConfig, float]:
    """Run the search; the fitted config and its score on the fit's seeds."""
    traits = args.traits
    objective = CohortObjective(engine, cfg, target, target_flows, args.participants, args.seed,
                                traits, args.flow_weight)
    t0 = time.monotonic()

    def progress(g: Generation) -> None:
        print(f"  generation {g.index}/{args.generations}: best {g.best:.3f}, so far "
              f"{g.best_so_far:.3f} ({time.monotonic() - t0:.0f} s)", flush=True)

    x, best = minimise(objective, to_unit(cfg, traits), args.generations,
                       args.popsize or default_popsize(len(traits)), args.sigma0, args.seed,
                       progress)
    return with_traits(cfg, from_unit(x, traits)), best


def main(argv: list[str] | None = None) -> int:
    """Fit (unless --evaluate), check on held-out people, print both tables, write the traits."""
    args = build_parser().parse_args(argv)
    args.argv = sys.argv[1:] if argv is None else argv  # for the fitted file's provenance
    holdout_seed = args.holdout_seed
    if holdout_seed is None:
        holdout_seed = args.seed + HOLDOUT_OFFSET
    fit_seeds = range(args.seed, args.seed + args.participants)
    if not args.evaluate and (holdout_seed < fit_seeds.stop
                              and fit_seeds.start < holdout_seed + args.holdout):
        return fail("nod calibrate-cohort", f"--holdout-seed {holdout_seed}: the held-out "
                    f"people must not be the fit's (seeds {fit_seeds.start}..{fit_seeds.stop - 1})")
    try:
        cfg = load_cohort_params(args.params)
        target = load_shares(_read(args.target or FIG8A), str(args.target or "Fig 8a"))
        target_flows = load_flows(_read(args.flows or FIG8B), str(args.flows or "Fig 8b"))
    except (ValueError, OSError) as exc:
        return fail("nod calibrate-cohort", exc)
    try:
        with engine_from_args(args) as engine:
            best = math.nan
            start = cfg
            if not args.evaluate:
                print(f"fitting {len(args.traits)} traits on {engine.where}:", flush=True)
                cfg, best = fit(engine, cfg, target, target_flows, args)
                print("traits: " + ", ".join(
                    f"{t.name} = {getattr(cfg.participant, t.name):.4f}" for t in args.traits))
            held = cohort_outcomes(engine, cfg, holdout_seed, args.holdout)
            held_start = (None if args.evaluate
                          else cohort_outcomes(engine, start, holdout_seed, args.holdout))
            where = engine.where
    except EngineError as exc:
        return fail("nod calibrate-cohort", exc)
    c = check(held, holdout_seed, target, target_flows)
    noise = study_noise(held, c, args.study_size, args.studies, args.seed)
    print(report(target, target_flows, c, noise))
    print(f"held out: Σ trial TVD {sum(c.trial_tvd.values()):.3f}, flows {c.flow_tvd:.3f}"
          + ("" if args.evaluate else f" (on the fit's own seeds: {best:.3f} in all)"))
    compared: list[str] = []
    if held_start is not None:
        compared = against_start(c, check(held_start, holdout_seed, target, target_flows),
                                 args.flow_weight)
        print("\n".join(compared))
    if args.out is not None and not args.evaluate:
        write_params(args.out, cfg, provenance(args, where, best, c, noise) + compared)
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
