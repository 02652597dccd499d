"""`nod cohort`: a simulated cohort on the compute engine, stored like a real study.

Each participant is one offline session (`services.model.closed_loop`: the same protocol machine and
model code the services run, in lock step, no fabric), with person-to-person variation drawn
from its seed around the default simulated person (the traits fitted to the paper,
`services.cohort.person`, unless `--params` says otherwise); sessions run on every core of a
local Dask cluster (or a lab's, `--scheduler`) and go, in seed order, into the same SQLite store
the conductor writes (sessions, trials, samples), so `nod report`, `nod export` and `nod analyze
study` work on the result. A simulated cohort is a model, not data: its sessions carry rig
"offline".

The store records each run as a cohort (`services.store.cohorts`): 'running' while it is
simulated, 'complete' at the end. A run whose cluster dies (or that is interrupted) marks it
'incomplete' and exits with the one command that finishes it, `nod cohort --db DB --resume`:
that drops a session left half-stored and simulates the participants not stored, with the
configuration and seeds the cohort was begun with, so the store ends as an uninterrupted run's
would. The analysis commands refuse a store holding an incomplete cohort.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sqlite3
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from services.cohort.person import load_cohort_params
from services.cohort.policy_file import (
    PolicyFile,
    make_policy,
    policy_from_bytes,
    read_policy_file,
)
from services.compute.engine import (
    Engine,
    EngineError,
    add_engine_args,
    engine_argv,
    engine_from_args,
)
from services.core.cli import SEED, Parser, fail, int_in
from services.core.config import ConfigError, from_mapping
from services.model.closed_loop import OfflineTrial, person_kind, run_offline_session
from services.model.params import NodConfig
from services.model.policy import PaperPolicy, Policy, spec_for
from services.model.protocol import TrialSpec
from services.store import Store, StoreError, TrialRecord
from services.store.cohorts import (
    CohortRecord,
    begin_cohort,
    drop_session,
    set_status,
    stored_sessions,
    unfinished,
)
from services.store.policies import cohort_policy, write_cohort_policy, write_policy

SESSION_SPACING_NS = 10**12  # each session's clock starts 1000 s after the previous one


@dataclass(frozen=True)
class Job:
    """One participant to simulate."""

    index: int  # 0-based position in the cohort
    seed: int
    cfg: NodConfig
    record: bool
    policy: Policy | None = None  # None: today's robot, stored without a policy


@dataclass(frozen=True)
class StoredPolicy:
    """The policy a cohort runs, as its sessions store it."""

    file: PolicyFile
    policy: Policy
    built_on: NodConfig | None = None  # the people its table was simulated from (adaptive)


def simulate(job: Job) -> list[OfflineTrial]:
    """Run one participant's session (a task on the engine)."""
    return run_offline_session(job.cfg, job.seed, cohort=True, record=job.record,
                               policy=job.policy)


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


def store_session(
    store: Store, job: Job, trials: list[OfflineTrial], prefix: str,
    policy: PolicyFile | None = None, config: dict | None = None,
) -> None:
    """Write one simulated session the way the conductor writes a real one (and its policy).

    In one transaction: a session is stored whole or not at all. `config`: the job's
    configuration summary when the caller has it (a cohort's sessions share one: building it
    anew for each cost ~2 ms of a ~40 ms session).
    """
    session = f"{prefix}-{job.seed}"
    base = (job.index + 1) * SESSION_SPACING_NS
    config = job.cfg.summary() if config is None else config
    with store.transaction():
        store.begin_session(session, f"P{job.index + 1:03d}", "offline", job.seed, base, config)
        for t in trials:
            spec = job.cfg.protocol.trials[t.trial - 1]
            spec = spec if t.settings is None else spec_for(spec, t.settings)  # the gaze played
            shift = base + t.trial * 60 * 10**9  # the trial's go, on the session's clock
            # Each as the store's Sample (`sample_row`): detected, on the session's clock, no
            # landmarks.
            rows = [(s[0] + base, True, *s[1:], None) for s in t.samples]
            t_go = rows[0][0] if rows else shift
            record = offline_record(t, spec, t_go)
            store.write_trial_rows(session, record, rows)
        if policy is not None:
            write_policy(store, session, policy.name, policy.sha256,
                         person_kind(job.cfg, job.seed),
                         {t.trial: t.settings for t in trials if t.settings is not None})
        store.finish_session(session, base + 59 * 60 * 10**9, "complete")


class CohortStoppedError(RuntimeError):
    """A cohort's run stopped before its end; the store marks it incomplete."""

    def __init__(self, why: str, cohort: CohortRecord, stored: int) -> None:
        super().__init__(why)
        self.why = why
        self.cohort = cohort
        self.stored = stored  # of its participants, stored in all


def config_json(cfg: NodConfig) -> dict:
    """The configuration as the store keeps it, checked to give `cfg` back exactly."""
    data = json.loads(json.dumps(dataclasses.asdict(cfg)))
    if from_mapping(NodConfig, data) != cfg:
        raise ValueError("this configuration does not survive JSON: a cohort of it cannot resume")
    return data


def run_cohort(
    engine: Engine,
    n: int,
    seed: int,
    db: Path,
    cfg: NodConfig,
    record: bool = True,
    prefix: str = "cohort",
    show: bool = True,
    policy: StoredPolicy | None = None,
) -> tuple[int, float]:
    """Simulate and store n participants; return (trials stored, seconds).

    CohortStoppedError if the engine fails half-way: the store then marks the cohort incomplete.
    `policy`: the robot's, stored with each session (None: today's robot, stored without one).
    """
    jobs = [Job(i, seed + i, cfg, record, None if policy is None else policy.policy)
            for i in range(n)]
    store = Store(db)
    try:
        taken = {s["session"] for s in store.sessions()} & {f"{prefix}-{j.seed}" for j in jobs}
        if taken:  # refused before any simulation, rather than a bare IntegrityError half-way
            first = min(taken, key=lambda s: int(s.rsplit("-", 1)[1]))
            raise StoreError(
                f"{db} already holds {len(taken)} of these sessions (e.g. {first}): choose "
                f"another --seed (seeds {seed}-{seed + n - 1} are taken in part) or another --db"
            )
        cohort = begin_cohort(store, prefix, seed, n, record, config_json(cfg))
        if policy is not None:
            built_on = policy.built_on if policy.built_on is not None else cfg
            write_cohort_policy(store, prefix, seed, policy.file.name, policy.file.sha256,
                                policy.file.text, json.dumps(config_json(built_on)))
        return _simulate(engine, store, cohort, jobs, show,
                         None if policy is None else policy.file)
    finally:
        store.close()


def resume_cohorts(
    engine: Engine, db: Path, show: bool = True
) -> list[tuple[CohortRecord, int, int, float]]:
    """Finish every incomplete cohort of the store; (cohort, participants run, trials, seconds).

    Each is simulated with the configuration and seeds it was begun with; a session left
    half-stored is dropped and run again. StoreError if there is nothing to resume.
    """
    store = Store(db)
    try:
        left = unfinished(store)
        if not left:
            raise StoreError(f"{db} holds no incomplete cohort: there is nothing to resume")
        done = []
        for cohort in left:
            try:
                cfg = from_mapping(NodConfig, json.loads(cohort.config))
            except (ValueError, ConfigError) as exc:
                raise StoreError(
                    f"the cohort {cohort.describe()} in {db} was begun by another version of "
                    f"nod-hri ({exc}); resume it with that version"
                ) from None
            status = stored_sessions(store, cohort)
            policy = _stored_policy(store, cohort, db, engine)
            for name, state in status.items():
                if state != "complete":
                    drop_session(store, name)
            jobs = [
                Job(i, s, cfg, cohort.samples, None if policy is None else policy.policy)
                for i, s in enumerate(cohort.seeds)
                if status.get(cohort.session(s)) != "complete"
            ]
            stored, seconds = _simulate(engine, store, cohort, jobs, show,
                                        None if policy is None else policy.file)
            done.append((cohort, len(jobs), stored, seconds))
        return done
    finally:
        store.close()


def _stored_policy(store: Store, cohort: CohortRecord, db: Path, engine: Engine
                   ) -> StoredPolicy | None:
    """The policy a cohort was begun with, rebuilt from the store (None: today's robot).

    From the policy file's text and the configuration its table was simulated from, both
    stored when the cohort began: the same file and people give the same table (its seeds
    are the file's), so the resumed sessions choose as the first run's did. A cohort begun
    before these were kept resumes only under the paper's robot, which needs neither.
    """
    ran = cohort_policy(store, cohort.prefix, cohort.first_seed)
    if ran is None:
        return None
    paper = read_policy_file("paper")
    if (ran.name, ran.sha256) == (paper.name, paper.sha256):
        return StoredPolicy(paper, PaperPolicy())
    if ran.text is None or ran.built_on is None:
        raise StoreError(
            f"the cohort {cohort.describe()} in {db} ran the policy {ran.name}, stored before "
            "nod-hri kept policy files with their cohort: run it again into a new --db")
    pf = policy_from_bytes(f"the cohort's stored policy {ran.name}", ran.name,
                           ran.text.encode())
    if pf.sha256 != ran.sha256:  # the text is the file's: a mismatch is a damaged row
        raise StoreError(f"the cohort {cohort.describe()} in {db}: its stored policy "
                         f"{ran.name} does not match its SHA-256; run it again into a new --db")
    try:
        built_on = from_mapping(NodConfig, json.loads(ran.built_on))
    except (ValueError, ConfigError) as exc:
        raise StoreError(f"the cohort {cohort.describe()} in {db}: its policy's people were "
                         f"stored by another version of nod-hri ({exc})") from None
    return StoredPolicy(pf, make_policy(pf, built_on, engine.imap), built_on)


def _simulate(
    engine: Engine, store: Store, cohort: CohortRecord, jobs: Sequence[Job], show: bool,
    policy: PolicyFile | None = None,
) -> tuple[int, float]:
    """Simulate and store jobs of a cohort, then mark it complete; (trials stored, seconds)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

    set_status(store, cohort, "running")
    t0 = time.monotonic()
    stored = 0
    columns = ("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
               TimeRemainingColumn())

    def stop(why: str) -> CohortStoppedError:
        set_status(store, cohort, "incomplete", why)
        have = sum(1 for v in stored_sessions(store, cohort).values() if v == "complete")
        return CohortStoppedError(why, cohort, have)

    try:
        with Progress(*columns, disable=not show, transient=True) as bar:
            task = bar.add_task("participants", total=len(jobs))
            configs: dict[int, dict] = {}  # the jobs' configuration summaries, by cfg
            for job, trials in zip(jobs, engine.imap(simulate, jobs), strict=True):
                if id(job.cfg) not in configs:
                    configs[id(job.cfg)] = job.cfg.summary()
                store_session(store, job, trials, cohort.prefix, policy, configs[id(job.cfg)])
                stored += len(trials)
                bar.advance(task)
    except EngineError as exc:
        raise stop(str(exc)) from None
    except sqlite3.IntegrityError:  # another `nod cohort` writes the same sessions
        raise stop("a session was stored by another process meanwhile") from None
    except KeyboardInterrupt:
        raise stop("interrupted") from None
    set_status(store, cohort, "complete")
    return stored, time.monotonic() - t0


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod cohort`."""
    p = Parser(
        prog="nod cohort",
        description="Simulate a cohort offline on every core (or a Dask cluster) and store it "
        "like a real study; participants are the fitted person unless --params says otherwise.",
    )
    p.add_argument("--participants", type=int_in(1, 10**5), default=None,
                   help="how many (1-100000; required unless --resume)")
    p.add_argument("--seed", type=SEED, default=None,
                   help="first seed (participant i: seed + i; default 1)")
    p.add_argument("--db", type=Path, required=True, help="session database to write")
    p.add_argument("--params", type=Path, default=None,
                   help="TOML overriding the fitted person and SPEC defaults")
    p.add_argument("--policy", default=None, metavar="paper|adaptive|FILE.toml",
                   help="the robot's policy (default paper: today's robot); its name and hash "
                   "and its settings per trial are stored with each session (docs/adaptive.md)")
    p.add_argument("--policy-params", type=Path, default=None, metavar="FILE.toml",
                   help="the people an adaptive policy's table is simulated from (default: "
                   "the cohort's own, --params): a policy tried on people it was not built for")
    p.add_argument("--resume", action="store_true",
                   help="finish the store's incomplete cohort (its participants, seeds and "
                   "configuration are in the store)")
    add_engine_args(p)
    p.add_argument("--no-samples", action="store_true", help="store trials only (smaller, faster)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def resume_command(args: argparse.Namespace) -> str:
    """The command that finishes the store's incomplete cohort, with the same engine."""
    argv = ["nod", "cohort", "--db", str(args.db), "--resume", *engine_argv(args)]
    return shlex.join([*argv, *(["--quiet"] if args.quiet else [])])


def stopped(args: argparse.Namespace, exc: CohortStoppedError) -> int:
    """Say in one line that the cohort stopped, what is stored, and how to finish it."""
    return fail(
        "nod cohort",
        f"{exc.why}; {exc.stored} of its {exc.cohort.participants} participants are stored and "
        f"{args.db} marks the cohort incomplete (no analysis takes it): once the cluster is back, "
        f"finish it with: {resume_command(args)}",
    )


def _resume(args: argparse.Namespace) -> int:
    given = [f for f, v in (("--participants", args.participants), ("--seed", args.seed),
                            ("--params", args.params), ("--no-samples", args.no_samples or None),
                            ("--policy", args.policy), ("--policy-params", args.policy_params))
             if v is not None]
    if given:
        return fail("nod cohort", f"--resume takes the cohort from the store: leave out "
                    f"{', '.join(given)}")
    if not args.db.is_file():
        return fail("nod cohort", f"no such database {args.db}: nothing to resume")
    t0 = time.monotonic()
    try:
        with engine_from_args(args) as engine:
            done = resume_cohorts(engine, args.db, show=not args.quiet)
            where = engine.where
    except CohortStoppedError as exc:
        return stopped(args, exc)
    except (EngineError, StoreError) as exc:
        return fail("nod cohort", exc)
    for cohort, ran, stored, seconds in done:
        print(
            f"resumed {cohort.describe()}: {ran} participants simulated ({stored} trials) in "
            f"{seconds:.1f} s on {where}; the cohort is complete -> {args.db}"
        )
    print(f"{time.monotonic() - t0:.1f} s with the engine's start and stop")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run `nod cohort`."""
    args = build_parser().parse_args(argv)
    if args.resume:
        return _resume(args)
    if args.participants is None:
        return fail("nod cohort", "--participants N is required (or --resume, to finish the "
                    "store's incomplete cohort)")
    seed = 1 if args.seed is None else args.seed
    try:
        cfg = load_cohort_params(args.params)
        policy_file = read_policy_file(args.policy or "paper")
        built_on = cfg if args.policy_params is None else load_cohort_params(args.policy_params)
        Store(args.db).close()
    except (ValueError, OSError, StoreError) as exc:
        return fail("nod cohort", exc)
    t0 = time.monotonic()
    try:
        with engine_from_args(args) as engine:
            policy = StoredPolicy(policy_file, make_policy(policy_file, built_on, engine.imap),
                                  built_on)
            stored, seconds = run_cohort(
                engine, args.participants, seed, args.db, cfg,
                record=not args.no_samples, show=not args.quiet, policy=policy,
            )
            where = engine.where
    except CohortStoppedError as exc:
        return stopped(args, exc)
    except (EngineError, StoreError, ValueError) as exc:
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
