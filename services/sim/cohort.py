"""`nod cohort`: a simulated cohort on the compute engine, stored like a real study.

Each participant is one offline session (`services.model.closed_loop`: the same protocol machine and
model code the services run, in lock step, no fabric), with person-to-person variation drawn
from its seed around the default simulated person (the traits fitted to the paper,
`services.cohort.person`, unless `--params` says otherwise); sessions run on every core of a
local Dask cluster (or a lab's, `--scheduler`) and go, in seed order, into the same SQLite store
the conductor writes (sessions, trials, samples), so `nod report`, `nod export` and `nod analyze
study` work on the result. A simulated cohort is a model, not data: its sessions carry rig
"offline".
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

from services.cohort.person import load_cohort_params
from services.compute.engine import Engine, EngineError, add_engine_args, engine_from_args
from services.core.cli import SEED, Parser, fail, int_in
from services.model.closed_loop import OfflineTrial, run_offline_session
from services.model.params import NodConfig
from services.model.protocol import TrialSpec
from services.store import Sample, Store, StoreError, TrialRecord

SESSION_SPACING_NS = 10**12  # each session's clock starts 1000 s after the previous one


@dataclass(frozen=True)
class Job:
    """One participant to simulate."""

    index: int  # 0-based position in the cohort
    seed: int
    cfg: NodConfig
    record: bool


def simulate(job: Job) -> list[OfflineTrial]:
    """Run one participant's session (a task on the engine)."""
    return run_offline_session(job.cfg, job.seed, cohort=True, record=job.record)


def offline_record(t: OfflineTrial, spec: TrialSpec, t_go_ns: int) -> TrialRecord:
    """The store's record of one simulated trial whose "go" was at t_go_ns."""
    return TrialRecord(
        trial=t.trial,
        mode=t.mode,
        option=t.option,
        gaze_level=spec.gaze_level,
        yaw=spec.gaze.yaw,
        pitch=spec.gaze.pitch,
        t_go_ns=t_go_ns,
        t_end_ns=t_go_ns + round(t.duration_s * 1e9),
        human=t.human,
        robot=t.robot,
        outcome=t.outcome,
        switches=t.switches,
        violations=t.violations,
        clicks=10,
        score=t.score,
        end_reason="human pressed" if t.human else "timeout",
    )


def store_session(store: Store, job: Job, trials: list[OfflineTrial], prefix: str) -> None:
    """Write one simulated session the way the conductor writes a real one."""
    session = f"{prefix}-{job.seed}"
    base = (job.index + 1) * SESSION_SPACING_NS
    store.begin_session(
        session, f"P{job.index + 1:03d}", "offline", job.seed, base, job.cfg.summary()
    )
    for t in trials:
        spec = job.cfg.protocol.trials[t.trial - 1]
        shift = base + t.trial * 60 * 10**9  # the trial's go, on the session's clock
        samples = [Sample(s.t_ns + base, True, *s[1:]) for s in t.samples]
        t_go = samples[0].t_ns if samples else shift
        record = offline_record(t, spec, t_go)
        store.write_trial(session, record, samples)
    store.finish_session(session, base + 59 * 60 * 10**9, "complete")


def run_cohort(
    engine: Engine,
    n: int,
    seed: int,
    db: Path,
    cfg: NodConfig,
    record: bool = True,
    prefix: str = "cohort",
    show: bool = True,
) -> tuple[int, float]:
    """Simulate and store n participants; return (trials stored, seconds)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

    jobs = [Job(i, seed + i, cfg, record) for i in range(n)]
    store = Store(db)
    taken = {s["session"] for s in store.sessions()} & {f"{prefix}-{j.seed}" for j in jobs}
    if taken:  # refused before any simulation, rather than a bare IntegrityError half-way
        store.close()
        first = min(taken, key=lambda s: int(s.rsplit("-", 1)[1]))
        raise StoreError(
            f"{db} already holds {len(taken)} of these sessions (e.g. {first}): choose another "
            f"--seed (seeds {seed}-{seed + n - 1} are taken in part) or another --db"
        )
    t0 = time.monotonic()
    stored = 0
    columns = ("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
               TimeRemainingColumn())
    try:
        with Progress(*columns, disable=not show, transient=True) as bar:
            task = bar.add_task("participants", total=n)
            for job, trials in zip(jobs, engine.imap(simulate, jobs), strict=True):
                store_session(store, job, trials, prefix)
                stored += len(trials)
                bar.advance(task)
    finally:
        store.close()
    return stored, time.monotonic() - t0


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod cohort`."""
    p = Parser(
        prog="nod cohort",
        description="Simulate a cohort offline on every core (or a Dask cluster) and store it "
        "like a real study; participants are the fitted person unless --params says otherwise.",
    )
    p.add_argument("--participants", type=int_in(1, 10**5), required=True,
                   help="how many (1-100000)")
    p.add_argument("--seed", type=SEED, default=1, help="first seed (participant i: seed + i)")
    p.add_argument("--db", type=Path, required=True, help="session database to write")
    p.add_argument("--params", type=Path, default=None,
                   help="TOML overriding the fitted person and SPEC defaults")
    add_engine_args(p)
    p.add_argument("--no-samples", action="store_true", help="store trials only (smaller, faster)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run `nod cohort`."""
    args = build_parser().parse_args(argv)
    try:
        cfg = load_cohort_params(args.params)
        Store(args.db).close()
    except (ValueError, OSError, StoreError) as exc:
        return fail("nod cohort", exc)
    t0 = time.monotonic()
    try:
        with engine_from_args(args) as engine:
            stored, seconds = run_cohort(
                engine, args.participants, args.seed, args.db, cfg,
                record=not args.no_samples, show=not args.quiet,
            )
            where = engine.where
    except (EngineError, StoreError) as exc:
        return fail("nod cohort", exc)
    total = time.monotonic() - t0
    rate = args.participants / seconds * 60
    print(
        f"{args.participants} simulated participants ({stored} trials) in {seconds:.1f} s "
        f"({rate:.0f}/min on {where}; {total:.1f} s with its start and stop) -> {args.db}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
