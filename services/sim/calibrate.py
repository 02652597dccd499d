"""`nod calibrate-cohort`: fit the simulated participant's traits to a table of outcome shares.

The target is a JSON file of per-trial shares of C, CH, D, DH (deploy/cohort/paper_fig8a.json
holds the paper's Fig 8a). A candidate set of traits is scored by simulating a cohort offline
(the same seeds for every candidate: common random numbers, so differences are the traits')
and summing, over trials, the total-variation distance between its shares and the target's
(a timeout counts as its own category, whose target share is 0). The search is seeded: a Latin
hypercube of candidates, then Nelder–Mead from the best. The result is a TOML file of
`[participant]` values beside the defaults, to pass as `--params` to `nod cohort` or `nod run`.

A cohort fitted to a table is a model of that table, not a replication of the study.
"""

from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize
from scipy.stats import qmc

from services.core.cli import SEED, Parser, fail, int_in
from services.core.config import load_params
from services.model.closed_loop import run_offline_session
from services.model.outcome import OUTCOMES
from services.model.params import NodConfig

CATEGORIES = (*OUTCOMES, "none")
SIMPLEX_STEP = 0.15  # Nelder–Mead's first steps, as a share of each trait's range


@dataclass(frozen=True)
class Trait:
    """One fitted participant trait and its search range."""

    name: str
    low: float
    high: float


TRAITS: tuple[Trait, ...] = (
    Trait("control_switch_prob", 0.0, 1.0),
    Trait("preference_mean", 0.5, 5.0),
    Trait("gaze_gain", 1.0, 15.0),
    Trait("gaze_gain_spread", 0.0, 1.5),
    Trait("trust0", 0.0, 2.0),
    Trait("trust_step", 0.0, 0.6),
    Trait("gaze_over_robot", 0.0, 5.0),
    Trait("speed", 0.2, 0.6),
    Trait("full_conviction", 0.1, 1.0),
    Trait("min_conviction", 0.0, 1.0),
)


def load_target(path: Path) -> dict[int, dict[str, float]]:
    """Per-trial target shares from a JSON file ({"trials": {"1": {"C": .., ...}, ...}})."""
    try:
        doc = json.loads(path.read_text())
        trials = {int(k): {c: float(v.get(c, 0.0)) for c in CATEGORIES} for k, v in
                  doc["trials"].items()}
    except (OSError, ValueError, KeyError, AttributeError, TypeError) as exc:
        raise ValueError(f"{path}: not a table of per-trial outcome shares ({exc})") from None
    for trial, shares in trials.items():
        total = sum(shares.values())
        if not 0.98 <= total <= 1.02:
            raise ValueError(f"{path}: trial {trial} shares add up to {total:.3f}, not 1")
    return trials


def shares(outcomes: list[list[str | None]]) -> dict[int, dict[str, float]]:
    """Per-trial shares of each category over a cohort's outcomes (one list per participant)."""
    out: dict[int, dict[str, float]] = {}
    n = len(outcomes)
    for k in range(len(outcomes[0])):
        counts = {c: 0 for c in CATEGORIES}
        for person in outcomes:
            counts[person[k] or "none"] += 1
        out[k + 1] = {c: counts[c] / n for c in CATEGORIES}
    return out


def tvd(a: dict[str, float], b: dict[str, float]) -> float:
    """Total-variation distance between two distributions over the categories."""
    return 0.5 * sum(abs(a.get(c, 0.0) - b.get(c, 0.0)) for c in CATEGORIES)


def _session(args: tuple[NodConfig, int]) -> list[str | None]:
    cfg, seed = args
    return [t.outcome for t in run_offline_session(cfg, seed, cohort=True)]


def with_traits(cfg: NodConfig, values: dict[str, float]) -> NodConfig:
    """The config with the participant's traits replaced."""
    traits = replace(
        cfg.participant,
        **values,  # type: ignore[arg-type]  # the keys: TRAITS' names, all float fields
    )
    return replace(cfg, participant=traits)


class Objective:
    """Σ_trials TVD(cohort shares, target) for a vector of traits in [0, 1]^k."""

    def __init__(
        self, cfg: NodConfig, target: dict[int, dict[str, float]], n: int, seed: int,
        pool: ProcessPoolExecutor,
    ) -> None:
        self.cfg, self.target, self.n, self.seed, self.pool = cfg, target, n, seed, pool
        self.evaluations = 0
        self.best: tuple[float, dict[str, float], dict[int, dict[str, float]]] | None = None

    def values(self, unit: np.ndarray) -> dict[str, float]:
        """The traits a point of the unit cube stands for."""
        u = np.clip(unit, 0.0, 1.0)
        return {t.name: t.low + (t.high - t.low) * float(x) for t, x in zip(TRAITS, u, strict=True)}

    def __call__(self, unit: np.ndarray) -> float:
        """Σ TVD of the cohort these traits make."""
        values = self.values(unit)
        cfg = with_traits(self.cfg, values)
        jobs = [(cfg, self.seed + i) for i in range(self.n)]
        got = shares(list(self.pool.map(_session, jobs, chunksize=4)))
        score = sum(tvd(got[k], want) for k, want in self.target.items())
        self.evaluations += 1
        if self.best is None or score < self.best[0]:
            self.best = (score, values, got)
        return score


def calibrate(
    cfg: NodConfig, target: dict[int, dict[str, float]], n: int, seed: int, starts: int,
    iterations: int, workers: int, log=print,
) -> tuple[dict[str, float], dict[int, dict[str, float]]]:
    """Fit the traits; return the best values and the shares of their cohort."""
    with ProcessPoolExecutor(max_workers=workers) as pool:
        objective = Objective(cfg, target, n, seed, pool)
        # The base traits (e.g. the last fit, given as --params) are candidate 0, so a refit after
        # a change to the participant model starts from what already worked.
        base = np.array([
            (getattr(cfg.participant, t.name) - t.low) / (t.high - t.low) for t in TRAITS
        ]).clip(0.0, 1.0)
        sampler = qmc.LatinHypercube(d=len(TRAITS), seed=seed)
        candidates = np.vstack([base, sampler.random(starts)])
        scores = [objective(c) for c in candidates]
        best = candidates[int(np.argmin(scores))]
        log(f"  the base traits: Σ TVD {scores[0]:.3f}; {starts} seeded candidates: best Σ TVD "
            f"{min(scores[1:]):.3f}")
        if iterations > 0:
            # scipy's default first simplex moves each trait by 5 % of its value (a trait at 0
            # never moves): too small to see past the cohort's sampling noise. Steps of
            # SIMPLEX_STEP of each range, toward the middle of the range, explore instead.
            simplex = np.tile(best, (len(best) + 1, 1))
            for i, x in enumerate(best):
                simplex[i + 1, i] = x + SIMPLEX_STEP if x <= 0.5 else x - SIMPLEX_STEP
            minimize(objective, best, method="Nelder-Mead",
                     options={"maxfev": iterations, "xatol": 0.01, "fatol": 0.005,
                              "initial_simplex": simplex})
        assert objective.best is not None
        score, values, got = objective.best
        log(f"  {objective.evaluations} cohorts of {n}: best Σ TVD {score:.3f}")
    return values, got


def write_params(path: Path, values: dict[str, float], source: str, n: int, seed: int) -> None:
    """The fitted traits as a `--params` file."""
    lines = [
        f"# Participant traits fitted by `nod calibrate-cohort` to {source}",
        f"# ({n} simulated participants per candidate, seeds {seed}..{seed + n - 1}).",
        "# A cohort fitted to a table is a model of that table, not a replication of it.",
        "[participant]",
    ]
    lines += [f"{name} = {value:.4f}" for name, value in values.items()]
    path.write_text("\n".join(lines) + "\n")


def table(target: dict[int, dict[str, float]], got: dict[int, dict[str, float]]) -> str:
    """Per trial: the target's and the cohort's shares, and their TVD."""
    rows = ["trial  target C/CH/D/DH          cohort C/CH/D/DH/none       TVD"]
    for k, want in sorted(target.items()):
        w = "/".join(f"{want[c] * 100:3.0f}" for c in OUTCOMES)
        g = "/".join(f"{got[k][c] * 100:3.0f}" for c in CATEGORIES)
        rows.append(f"{k:>5}  {w:<25} {g:<27} {tvd(got[k], want):.3f}")
    return "\n".join(rows)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod calibrate-cohort`."""
    p = Parser(prog="nod calibrate-cohort", description=__doc__.splitlines()[0])
    p.add_argument("--target", type=Path, required=True, help="per-trial shares (JSON)")
    p.add_argument("--out", type=Path, default=None, help="write the fitted traits here (TOML)")
    p.add_argument(
        "--params", type=Path, default=None,
        help="base parameters (TOML); its traits are also the search's first candidate",
    )
    p.add_argument("--participants", type=int_in(1, 10**5), default=60,
                   help="cohort size per candidate (60)")
    p.add_argument("--seed", type=SEED, default=1, help="first seed of the cohort (1)")
    p.add_argument("--starts", type=int_in(1, 10_000), default=24, help="seeded candidates (24)")
    p.add_argument("--iterations", type=int_in(1, 10**5), default=40,
                   help="Nelder–Mead evaluations (40)")
    p.add_argument("--workers", type=int_in(1, 1024), default=os.cpu_count() or 1, help="processes")
    p.add_argument(
        "--evaluate", action="store_true",
        help="fit nothing: score the --params cohort against the target (use a fresh --seed "
        "to check a fit on people it was not fitted to)",
    )
    return p


def evaluate(
    cfg: NodConfig, n: int, seed: int, workers: int
) -> dict[int, dict[str, float]]:
    """The per-trial outcome shares of a cohort of n people with seeds seed..seed+n-1."""
    with ProcessPoolExecutor(max_workers=workers) as pool:
        jobs = [(cfg, seed + i) for i in range(n)]
        return shares(list(pool.map(_session, jobs, chunksize=4)))


def main(argv: list[str] | None = None) -> int:
    """Fit, print the per-trial fit, write the traits."""
    args = build_parser().parse_args(argv)
    if not (2 <= args.participants <= 10_000 and 1 <= args.starts <= 1000):
        return fail("nod calibrate-cohort", "--participants 2-10000, --starts 1-1000")
    try:
        cfg = load_params(args.params)
        target = load_target(args.target)
    except (ValueError, OSError) as exc:
        return fail("nod calibrate-cohort", exc)
    if args.evaluate:
        got = evaluate(cfg, args.participants, args.seed, args.workers)
        print(f"{args.participants} participants (seeds {args.seed}.."
              f"{args.seed + args.participants - 1}) against {args.target}:")
        print(table(target, got))
        print(f"Σ TVD {sum(tvd(got[k], w) for k, w in target.items()):.3f}")
        return 0
    print(f"fitting {len(TRAITS)} traits to {args.target}:")
    values, got = calibrate(
        cfg, target, args.participants, args.seed, args.starts, args.iterations, args.workers
    )
    print(table(target, got))
    print("traits: " + ", ".join(f"{k} = {v:.3f}" for k, v in values.items()))
    if args.out is not None:
        write_params(args.out, values, str(args.target), args.participants, args.seed)
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
