"""`nod run --sim`: a Zenoh router plus every service as its own OS process, one session.

The router runs inside this process (any Zenoh client can connect to `--listen` and watch every
key); decision, actuation, eyes, the sim participant and the experiment conductor are started as
child processes connected to it, sharing one simulated clock (`--speed`), under the same
`Supervisor` as `nod up`: a service that dies is restarted with backoff (the conductor resumes
its session, so the trial in progress is repeated), a crash loop is given up and fails the run,
and every such event is printed and published on rig/event. The conductor's trial events drive a
progress line and a per-trial table; when it exits, the others are stopped. A run stopped before
its session's last trial (Ctrl-C, a service given up) prints `resume with: nod run --sim
--resume SESSION …`, which starts the rig again with a conductor resuming that session.
"""

from __future__ import annotations

import argparse
import functools
import logging
import os
import shlex
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh

from services.core import messages as m
from services.core.cli import SEED, Parser, add_options_arg, fail, int_in
from services.core.clock import Clock
from services.core.config import load_with_options
from services.core.keys import Keys, check_rig
from services.core.lifeline import nod_command
from services.core.rigfile import Host, Rig
from services.core.session import DEFAULT_ROUTER, make_config, open_session
from services.core.signals import on_stop_signal
from services.experiment.resume import (
    flag_argv,
    resume_argv,
    resume_line,
    resume_problem,
    session_status,
    stored_unfinished,
)
from services.launch.commands import command
from services.launch.events import RigEvents
from services.launch.rigs import RIG_FLAGS, check_rigs, next_seed, run_rigs
from services.launch.run_logs import LogWatch, run_folder
from services.launch.supervisor import RestartPolicy, ServiceSpec, Supervisor
from services.launch.view import SessionView, session_view
from services.model.geometry import COLOURS
from services.safety.latch_file import STATE_DIR_ENV
from services.store import Store, StoreError
from services.store.participants import next_free_ids, reuse_problem

log = logging.getLogger("nod.run")
# And the conductor, "experiment". The speaker (`--driver sim`: silent) is not required by a
# trial; it reports the cues' onsets, stored with each trial. The sim comes last: it is per person.
SERVICES = ("decision", "actuation", "eyes", "speaker", "sim")
# Every service that reads the table gets `--options N` with a table of N boxes (the eyes need
# none: the conductor sends them a gaze toward a box, as ever)
TABLE_READERS = ("decision", "actuation", "sim", "vision", "experiment")
# The watchdogs judge freshness in wall time (250 ms): below 0.5x the sim camera (30 Hz of sim
# time) and the gaze keep-alive (20 Hz) come too slowly; above 10x a 2-core host cannot carry
# the message rates (30 Hz x speed poses, each answered three times) without late inputs.
MIN_SPEED, MAX_SPEED = 0.5, 10.0
# What a resumed run keeps of the interrupted one (argparse dests; a session keeps its own
# participant, seed and order).
RESUME_FLAGS = (
    "speed", "listen", "rig", "params", "options", "clicks", "stale_ms", "logs", "record", "render",
    "arm_driver", "arm_port", "arm_config", "eyes_driver", "eyes_port", "eyes_config",
    "eyes_trims", "verbose", "policy", "estimate",
)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod run`."""
    p = Parser(
        prog="nod run",
        description="Start a Zenoh router and every service as separate processes, and run one "
        "participant's 8 trials. With --sim a synthetic participant stands in for the camera "
        "and the person, and simulated arm and eyes stand in for the hardware.",
    )
    p.add_argument("--sim", action="store_true", help="simulate participant, arm and eyes")
    p.add_argument("--db", type=Path, default=Path("nod-sessions.sqlite"), help="session store")
    p.add_argument(
        "--seed",
        type=SEED,
        default=None,
        help="seed of the simulated participant (default: one past the largest seed stored in "
        "--db, 1 in a new one: a run added to a store is a new simulated person)",
    )
    p.add_argument("--speed", type=float, default=1.0, help="simulated seconds per wall second")
    p.add_argument("--listen", default=DEFAULT_ROUTER, help=f"router endpoint ({DEFAULT_ROUTER})")
    p.add_argument("--rig", type=check_rig, default="rig1", help="rig name scoping every key")
    p.add_argument(
        "--participant",
        default=None,
        help="participant id stored with the session (default: the first of P01, P02, … with "
        "no session in --db); one with a complete session is refused without --again",
    )
    p.add_argument("--order", default=None, metavar="O,O,...",
                   help="O of each consensus trial (`nod experiment --order`)")
    p.add_argument("--again", default=None, metavar="REASON",
                   help="a new session for a participant who has one (`nod experiment --again`)")
    p.add_argument(
        "--resume",
        default=None,
        metavar="SESSION",
        help="go on with a stored session of --db at its next trial (after Ctrl-C or a crash: "
        "the line the run printed); its participant, seed and order are its own",
    )
    p.add_argument(
        "--monitor",
        nargs="?",
        const="--spawn",
        default=None,
        metavar="ARGS",
        help="also start `nod monitor` with these arguments (default --spawn), e.g. "
        "--monitor='--save session.rrd' or --monitor=--serve-web",
    )
    p.add_argument(
        "--render",
        action="store_true",
        help="run the camera path too: the sim renders frames, `nod vision` tracks the marker",
    )
    p.add_argument(
        "--participants",
        type=int_in(1, 10_000),
        default=1,
        help="run N simulated participants one after another (the first free ids P01.., seeds "
        "seed..seed+N-1, person-to-person variation drawn from each seed), all in one database",
    )
    p.add_argument("--rigs", type=int_in(1, 16), default=1, metavar="N",
                   help="run N simulated rigs at once on this router (rig1..rigN), the "
                   "participants split across them, each rig's sessions in <db>-<rig>.sqlite")
    p.add_argument("--join", action="store_true", help=argparse.SUPPRESS)  # a rig of --rigs
    p.add_argument("--ids", type=lambda s: s.split(","), default=None, help=argparse.SUPPRESS)
    p.add_argument("--clicks", default="10",
                   help="the counter clicks of every trial: N (default 10: the simulated person "
                   "counts right), 'prompt' (asked after each trial is stored) or 'none'")
    p.add_argument("--params", type=Path, default=None, help="TOML overriding SPEC defaults")
    p.add_argument("--study", type=Path, default=None, metavar="STUDY.toml",
                   help="the study file of the session (`nod experiment --study`: provenance)")
    p.add_argument("--stale-ms", type=float, default=None, help="safety staleness bound (ms)")
    p.add_argument(
        "--logs",
        type=Path,
        default=None,
        help="folder for service logs, as given (default: a new folder per run, "
        "<db>.logs/<YYYYmmdd-HHMMSS>/, never one used before)",
    )
    p.add_argument(
        "--record",
        type=Path,
        default=None,
        metavar="DIR",
        help="record each session's keys to DIR/<session>.mcap (`nod experiment --record`)",
    )
    p.add_argument("--policy", default=None, metavar="paper|adaptive|FILE.toml",
                   help="the robot policy (`nod experiment --policy`, docs/adaptive.md); any but "
                   "paper also starts `nod estimate`")
    p.add_argument("--estimate", default=None, metavar="ARGS",
                   help="run `nod estimate` with these flags (e.g. '--table 500'; '' for its "
                   "defaults): the participant's parameters after each trial, stored with it")
    hw = p.add_argument_group("bench-testing real hardware with the sim participant")
    hw.add_argument("--arm-driver", default="sim", help="sim | feetech (default sim)")
    hw.add_argument("--arm-port", default=None, help="serial port of the arm")
    hw.add_argument("--arm-config", type=Path, default=None, help="arm file with calibrated poses")
    hw.add_argument("--eyes-driver", default="sim", help="sim | maestro | arduino (default sim)")
    hw.add_argument("--eyes-port", default=None, help="serial port of the eyes controller")
    hw.add_argument("--eyes-config", type=Path, default=None, help="eyes hardware file")
    hw.add_argument(
        "--eyes-trims", type=Path, default=None, help="eyes trims file (`nod eyes calibrate`)"
    )
    add_options_arg(p)
    p.add_argument("-v", "--verbose", action="store_true", help="services log at debug level")
    return p


def sim_rig(args: argparse.Namespace) -> Rig:
    """The rig `nod run` runs: every service on this machine, as an in-memory rig file says it.

    What is run-specific (the participant's sim and conductor flags) rides in each service's
    `args`, as a rig file's `args` would; everything else is the rig file's vocabulary.
    """
    services: tuple[str, ...] = (*SERVICES, "vision", "experiment")
    sections: dict[str, dict[str, Any]] = {
        "vision": {"source": "zenoh:sim/camera", "tracker": "aruco"},
        "sim": {"seed": args.seed, "args": [
            *(["--render"] if args.render else []),
            *(["--cohort"] if getattr(args, "cohort", False) else []),
        ]},
    }
    for service, prefix in (("actuation", "arm"), ("eyes", "eyes")):
        sec: dict[str, Any] = {"driver": getattr(args, f"{prefix}_driver")}
        for key, value in (
            ("port", getattr(args, f"{prefix}_port")),
            ("config", getattr(args, f"{prefix}_config")),
            ("stale_ms", args.stale_ms),
            ("state_dir", getattr(args, "state_dir", None)),
            ("trims", getattr(args, "eyes_trims", None) if service == "eyes" else None),
        ):
            if value is not None:
                sec[key] = value
        sections[service] = sec
    conductor = ["--db", str(args.db), "--seed", str(args.seed), "--clicks", args.clicks]
    if args.participant is not None:  # else the conductor takes the first free id
        conductor += ["--participant", args.participant]
    for flag in ("order", "again"):
        if getattr(args, flag, None) is not None:
            conductor += [f"--{flag}", getattr(args, flag)]
    if getattr(args, "session", None):
        conductor += ["--session", args.session]
    if getattr(args, "record", None) is not None:
        conductor += ["--record", str(args.record)]
    if getattr(args, "study", None) is not None:
        conductor += ["--study", str(args.study.resolve())]
    if getattr(args, "policy", None) is not None:
        conductor += ["--policy", args.policy]
    sections["experiment"] = {"args": conductor}
    if estimating(args):
        services = (*services, "estimate")
        sections["estimate"] = {"args": shlex.split(args.estimate or "")}
    if getattr(args, "options", None) is not None:  # a table of N boxes: every reader of it
        for service in TABLE_READERS:
            sec = sections.setdefault(service, {})
            sec["args"] = [*sec.get("args", []), "--options", str(args.options)]
    return Rig(
        path=Path("nod run --sim"),
        name=args.rig,
        router=args.listen,
        hosts={"here": Host("here", services, router=True)},
        params=args.params,
        sections=sections,
    )


def estimating(args: argparse.Namespace) -> bool:
    """Whether the run starts `nod estimate`: asked for, or a policy other than the paper's."""
    return (getattr(args, "estimate", None) is not None
            or getattr(args, "policy", None) not in (None, "paper"))


def child_command(service: str, args: argparse.Namespace, epoch_ns: int) -> list[str]:
    """The command line of one child service (the launchers' one builder)."""
    return command(sim_rig(args), service, clock=(args.speed, epoch_ns), verbose=args.verbose)


def main(argv: list[str] | None = None) -> int:
    """Run the session(s) on the fabric; exit 0 when every trial is stored."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    problem = _check_args(args) or check_rigs(args)
    if problem is None and args.rigs == 1:  # with --rigs, each rig's own run checks the rest
        problem = _preflight(args)
    if problem:
        return fail("nod run", f"{problem}")
    if args.rigs > 1:  # several rigs, each a `nod run --join` of its own
        return run_rigs(args, flag_argv(build_parser(), args, RIG_FLAGS))
    logs: Path = args.log_dir  # made by the preflight: this run's own
    # A simulated device is a new device every run: its e-stop latch lives in a folder of this
    # run (still surviving the restarts of its service within the run). A real arm or real eyes
    # keep theirs where they always do (`--state-dir`'s default), across runs too.
    sim_state = None
    if args.arm_driver == "sim" and args.eyes_driver == "sim" and not os.environ.get(
        STATE_DIR_ENV
    ):
        sim_state = tempfile.TemporaryDirectory(prefix="nod-sim-state-")
        args.state_dir = Path(sim_state.name)
    try:  # a rig of `--rigs` joins the run's router as a client
        router = open_session(make_config(mode="client", connect=[args.listen]) if args.join
                              else make_config(mode="router", listen=[args.listen]))
    except ConnectionError as exc:
        return fail("nod run", f"cannot listen on {args.listen}: {exc}")
    view = session_view(*load_with_options(args.params, args.options), args.participants > 1)
    keys = Keys(args.rig)
    subs = view.subscribe(router, keys)
    epoch_ns = time.time_ns()
    print(
        f"router listening on {args.listen}; rig {args.rig!r}; speed {args.speed}x; "
        f"{args.participants} participant(s); logs in {logs}/",
        flush=True,
    )
    if args.resume is not None:  # the table goes on from the trials stored before
        view.begin(args.participant)
        earlier = _stored_results(args.db, args.resume)
        print(f"resuming session {args.resume} ({args.participant}): {len(earlier)} trial(s) "
              "stored before", flush=True)
        for result in earlier:
            view.on_result(result)
    monitor = _start_monitor(args, router, keys, logs) if args.monitor is not None else None
    events = RigEvents(router, keys, Clock(args.speed, epoch_ns))
    supervisor = Supervisor(RestartPolicy(), on_event=events)
    stopping = threading.Event()
    on_stop_signal(lambda _signum: stopping.set())  # never set() inside a handler
    code = 1
    session = args.resume
    try:
        rig = [*SERVICES[:-1], *(["vision"] if args.render else []),
               *(["estimate"] if estimating(args) else [])]
        for service in rig:  # the rig: decision, actuation, eyes, speaker (, vision) stay up
            supervisor.start(_spec(service, args, epoch_ns, logs))
        for i in range(args.participants):
            person = _participant(args, i)
            session = person.session
            if args.resume is None:
                view.begin(person.participant)
            suffix = f"-{i + 1}-{person.participant}"  # whose logs they are, in their names
            for service in ("sim", "experiment"):  # a new person: new sim, new conductor
                supervisor.start(_spec(service, person, epoch_ns, logs, suffix=suffix))
            code = _supervise(supervisor, stopping, _waiting_lines(args, supervisor, view))
            supervisor.stop(["sim", "experiment"])
            if code != 0:
                break
    finally:
        supervisor.stop()
        if monitor is not None:  # outside the supervisor: a closed viewer must not fail the run
            _stop_all({"monitor": monitor}, grace_s=20.0)  # time to write the .rrd's footer
        for sub in subs:
            sub.undeclare()
        router.close()
        if sim_state is not None:
            sim_state.cleanup()
    if code == 0:
        print(
            f"{view.total_trials} trials of {args.participants} participant(s) stored in "
            f"{args.db}; service logs in {logs}/"
        )
    elif code == 130:
        print("\ninterrupted: every service stopped", file=sys.stderr)
    else:
        _explain_failure(logs)
    if code != 0 and session is not None and stored_unfinished(args.db, session):
        resumed = resume_argv(build_parser(), args, session, ("nod", "run", "--sim"),
                              RESUME_FLAGS)
        print(resume_line(resumed), file=sys.stderr, flush=True)
    return code


def _stored_results(db: Path, session: str) -> list[m.TrialResult]:
    """The trials a resumed session has stored, as the results the table shows."""
    store = Store(db)
    try:
        trials = [t for _, t in store.trials(session)]
        options = store.option_names(session)  # the session's option set, by name
    finally:
        store.close()
    names = ("trial", "mode", "option", "robot", "human", "outcome", "switches", "violations",
             "score", "interrupted")
    out = []
    for t in trials:
        fields: dict[str, Any] = {name: getattr(t, name) for name in names}
        out.append(m.TrialResult(seq=0, t_ns=t.t_end_ns or 0, session=session, options=options,
                                 **fields))
    return out


def _start_monitor(args: argparse.Namespace, router, keys: Keys, logs: Path) -> subprocess.Popen:
    """Start `nod monitor` and wait until it listens, so trial 1 is recorded from its setup."""
    proc = subprocess.Popen(
        nod_command("monitor", "--connect", args.listen, "--rig", args.rig,
                    *shlex.split(args.monitor)),
        stdout=(logs / "monitor.log").open("w"),
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        start_new_session=True,
    )
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and proc.poll() is None:
        if list(router.liveliness().get(keys.alive("monitor"), timeout=0.5)):
            break
        time.sleep(0.1)
    print(f"monitor: nod monitor {args.monitor} (log in {logs}/monitor.log)", flush=True)
    for line in monitor_lines(logs / "monitor.log"):  # e.g. the web viewer's URL, the .rrd
        print(f"monitor: {line}", flush=True)
    return proc


def monitor_lines(log: Path) -> list[str]:
    """What `nod monitor` said at start (its sinks: web viewer URL, recording, or an error).

    It prints these before it declares its liveliness token, so they are in its log by the
    time `_start_monitor` sees the monitor up.
    """
    try:
        text = log.read_text(errors="replace")
    except OSError:
        return []
    prefix = "nod monitor: "
    return [line[len(prefix) :] for line in text.splitlines() if line.startswith(prefix)]


def _check_args(args: argparse.Namespace) -> str | None:
    if not args.sim:
        return (
            "only --sim is available from this command; on a rig, start each service with "
            "its own command (see deploy/)"
        )
    if not MIN_SPEED <= args.speed <= MAX_SPEED:
        return (
            f"--speed must be in [{MIN_SPEED}, {MAX_SPEED}], got {args.speed}: the safety bounds "
            "hold in wall time, so slower runs starve them and faster ones overload the host"
        )
    if not 1 <= args.participants <= 1000:
        return f"--participants must be in [1, 1000], got {args.participants}"
    if args.resume is not None:
        given = [f for f in ("participant", "again", "order") if getattr(args, f) is not None]
        if args.participants != 1 or given:
            flags = ", ".join(f"--{f}" for f in given) or "--participants"
            return (
                f"--resume goes on with one stored session, with its own participant, seed and "
                f"order: leave out {flags}"
            )
    return None


def _options_problem(args: argparse.Namespace, names: tuple[str, ...]) -> str | None:
    """Why this run cannot go with these options (one line), or None.

    The whole rig runs any option set, the paper's run's flags with it; a Feetech arm needs a
    press pose for every option in its file (actuation checks it too: here it fails first).
    """
    if args.arm_driver != "feetech" or args.arm_config is None:
        return None
    from services.actuation.drivers import check_arm_file  # only a real arm's run pays for it

    try:
        check_arm_file(args.arm_config, names)
    except ValueError as exc:  # ConfigError is a ValueError
        return str(exc)
    return None


def _preflight(args: argparse.Namespace) -> str | None:
    """Everything that can be checked before a process starts, as one line each."""
    try:
        _, schedule = load_with_options(args.params, args.options)
    except (ValueError, OSError) as exc:  # ConfigError is a ValueError
        return str(exc)
    if schedule is not None and (problem := _options_problem(args, schedule.names)):
        return problem
    try:
        make_config(mode="router", listen=[args.listen])
    except zenoh.ZError:
        return f"--listen {args.listen!r} is not a zenoh endpoint (e.g. tcp/127.0.0.1:7447)"
    try:
        store = Store(args.db)
    except StoreError as exc:
        return str(exc)
    try:  # who runs: the ids given, or the first free ones; a done participant needs --again
        if args.resume is not None:  # the stored session's own participant and seed
            names = COLOURS if schedule is None else schedule.names
            if problem := resume_problem(store, args.resume, args.rig, names):
                return problem  # not there, another rig's, complete, another option set
            known = {s["session"]: s for s in store.sessions()}
            args.ids = [known[args.resume]["participant"]]
            if known[args.resume]["seed"] is not None:
                args.seed = known[args.resume]["seed"]
        elif args.ids is not None:  # a rig of `--rigs`: its block of the study's ids
            pass
        elif args.participant is None or args.participants > 1:
            args.ids = next_free_ids(store, args.participants)
        else:
            args.ids = [args.participant]
            if args.again is None and (problem := reuse_problem(store, args.participant, True)):
                return problem
        args.participant = args.ids[0]
        if args.seed is None:  # the store's sequence goes on: never a stored person again
            args.seed = next_seed([store])
    finally:
        store.close()
    try:
        args.log_dir = log_dir(args)
    except OSError as exc:
        return f"cannot write service logs to {args.logs or _logs_base(args.db)}: {exc.strerror}"
    return None


def log_dir(args: argparse.Namespace) -> Path:
    """The run's log folder: `--logs` as given, else a new one under `<db>.logs/` (OSError).

    A folder is never reused by default: each run (a participant's, a resumed one's, each of a
    study's `nod study start --sim`) keeps the logs of every run before it.
    """
    if args.logs is not None:  # the operator's (or a rig of `--rigs`: its folder of the run)
        args.logs.mkdir(parents=True, exist_ok=True)
        return Path(args.logs)
    return run_folder(_logs_base(args.db))


def _logs_base(db: Path) -> Path:
    """Where the run folders of a store's runs go: `<db>.logs/`."""
    return db.with_suffix(".logs")


def _participant(args: argparse.Namespace, i: int) -> argparse.Namespace:
    """The arguments of participant i: its own seed, id and session; a cohort varies traits.

    The launcher names the session, so a conductor it restarts can resume that very session.
    """
    extra: dict[str, object] = {"session": args.resume or uuid.uuid4().hex[:12]}
    if args.participants > 1 or args.join:  # a rig of `--rigs` runs a share of a cohort
        extra |= {"seed": args.seed + i, "participant": args.ids[i], "cohort": True}
    return argparse.Namespace(**{**vars(args), **extra})


def _spec(
    service: str, args: argparse.Namespace, epoch_ns: int, logs: Path, suffix: str = ""
) -> ServiceSpec:
    """A supervised child; a restarted conductor resumes its session instead of starting one."""
    cmd = child_command(service, args, epoch_ns)
    resume = None
    if service == "experiment":
        at = cmd.index("--session")
        resumed = [*cmd[:at], "--resume", cmd[at + 1], *cmd[at + 2 :]]
        resume = functools.partial(conductor_restart, Path(args.db), cmd[at + 1], cmd, resumed)
        if getattr(args, "resume", None) is not None:  # `nod run --resume`: from the start
            cmd = resumed
    log_path = logs / f"{service}{suffix}.log"
    log_path.write_text("")  # a fresh log per run; restarts append to it
    return ServiceSpec(service, cmd, log=log_path, restart_argv=resume)


def conductor_restart(
    db: Path, session: str, fresh: list[str], resumed: list[str]
) -> list[str] | None:
    """A dead conductor's restart, by what the store holds of its session.

    Stored and unfinished: resume it. Not stored (it died before its first write): start it
    again as it was started. Complete (it died after storing its end): nothing to do — a resume
    of a complete session is refused, and the supervisor gave up on a run whose every trial was
    stored.
    """
    try:
        status = session_status(db, session)
    except (OSError, StoreError):  # the store unreadable: the resume itself will say why
        return resumed
    if status is None:
        return fresh
    return None if status == "complete" else resumed


def _waiting_lines(
    args: argparse.Namespace, supervisor: Supervisor, view: SessionView
) -> Callable[[], None]:
    """Say here each trial the conductor says (in its log) waits for the operator's start."""
    log_path = supervisor.services["experiment"].spec.log
    if log_path is None:
        return lambda: None
    watch = LogWatch(log_path)
    flags = "".join(f" --{flag} {value}" for flag, value, default in (
        ("connect", args.listen, DEFAULT_ROUTER), ("rig", args.rig, "rig1")) if value != default)
    hint = f" (here: nod experiment next{flags})"

    def say() -> None:
        for line in watch.new():
            view.note(line + hint)

    return say


def _supervise(
    supervisor: Supervisor, stopping: threading.Event, each: Callable[[], None] = lambda: None
) -> int:
    """Supervise until the conductor finishes; a service given up on fails the run."""
    while not stopping.is_set():
        supervisor.poll()
        each()
        conductor = supervisor.services["experiment"]
        if conductor.state == "done":
            return 0
        failed = supervisor.failed()
        if failed:
            for name in failed:
                code = supervisor.services[name].last_code
                how = _how(code) if code is not None else "failed"
                print(f"\nnod run: service {name} {how} and was given up on", file=sys.stderr)
            return 1
        for name, s in supervisor.services.items():  # a service ended "normally" mid-session
            if name != "experiment" and s.state == "done":
                print(f"\nnod run: service {name} exited mid-session", file=sys.stderr)
                return 1
        stopping.wait(0.05)
    return 130


def _how(rc: int) -> str:
    """How a child ended, in words: an exit code, or the signal that killed it."""
    if rc < 0:
        try:
            name = signal.Signals(-rc).name
        except ValueError:
            name = f"signal {-rc}"
        return f"was killed by {name}"
    return f"exited with code {rc}"


def _stop_all(children: dict[str, subprocess.Popen], grace_s: float = 5.0) -> None:
    """SIGTERM every child (they stop cleanly), then kill what is left after `grace_s`."""
    for proc in children.values():
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    for proc in children.values():
        try:
            proc.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _explain_failure(logs: Path) -> None:
    """Show the end of the most recently written service logs."""
    for path in sorted(logs.glob("*.log"), key=lambda p: p.stat().st_mtime)[-3:]:
        tail = path.read_text(errors="replace").splitlines()[-6:]
        print(f"--- {path.name}, last lines:", file=sys.stderr)
        print("\n".join(tail), file=sys.stderr)


if __name__ == "__main__":
    raise SystemExit(main())
