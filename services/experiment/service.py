"""`nod experiment`: the command line of the conductor of one participant's session.

The conductor itself is `services.experiment.conductor.Conductor`; this module reads the
flags, opens (or resumes) the session in the store, refuses a second conductor on the rig,
starts the recorder when asked, and runs the session. One command line for any option set:
`--options N` (or a params file's `[protocol] options`) picks the session's key space
(`services.experiment.keyspace`), and every flag means the same at N options.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import logging
import math
import socket
import sys
import time
import uuid
from collections.abc import Callable
from pathlib import Path

from services.core.cli import SEED, add_options_arg, fail, service_parser
from services.core.config import load_with_options, params_hash
from services.core.node import Node, package_version, setup_logging
from services.core.provenance import HostsSeen, Provenance, make_provenance, metadata
from services.core.rigfile import CONTROL, Host, RigFileError, load_rig, session_flags
from services.core.session import Fabric
from services.experiment.conductor import Conductor
from services.experiment.console import make_console
from services.experiment.keyspace import key_space
from services.experiment.order import participant_problem, session_keys
from services.experiment.params_check import ParamsCheck
from services.experiment.policy_link import load_choice
from services.experiment.policy_link import resume_problem as policy_resume_problem
from services.experiment.recording import RecorderProcess, recorder_command, recording_path
from services.experiment.resume import (
    prepare_resume,
    resume_problem,
    say_how_to_resume,
    warn_of_interrupted,
)
from services.experiment.rig_claim import claim_the_rig, watch_rivals
from services.experiment.waiting import hear_the_devices
from services.store import Store, back_up
from services.store.participants import next_free_ids, record_order
from services.store.provenance import finish_provenance, write_provenance

log = logging.getLogger("nod.experiment")
RECORDER_READY_S = 30.0  # wall seconds for `nod record` to start and subscribe
HEAR_DEVICES_S = 5.0  # wall seconds to hear the devices before declaring this conductor alive


def ask_clicks(
    trial: int, read_line: Callable[[str], str] = input, target: int = 10
) -> int | None:
    """Prompt the operator for the counter value of a trial (empty → not entered).

    `read_line` asks (the console's own prompt: a line of its live panel, or the terminal's).
    The question says what is counted and the target: an operator who typed 0 for every trial
    showed the participant "0 points" seven times. The trial is already stored; the answer
    updates it (`Store.set_clicks`), and `nod clicks` enters or corrects it later.
    """
    question = (f"trial {trial}: counter clicks — the number the participant counted "
                f"(target {target}; Enter alone = not entered)? ")
    while True:
        try:
            raw = read_line(question).strip()
        except EOFError:
            return None
        if not raw:
            return None
        if raw.isdigit():
            return int(raw)
        question = f"{raw[:20]!r} is not a whole number ≥ 0 — trial {trial}: counter clicks? "


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod experiment`."""
    p = service_parser(
        "nod experiment",
        "Conduct one participant's 8 trials and store them in a SQLite file.",
    )
    p.add_argument(
        "--rig-file",
        type=Path,
        default=None,
        metavar="RIG.toml",
        help="take the rig name, the router (or, with rig.tls, the control station's identity) "
        "and --params from a rig file, as `nod up` gives them to its services; flags given "
        "here win",
    )
    p.add_argument(
        "--allow-params-mismatch",
        action="store_true",
        help="run even when decision or actuation publish another params hash than this "
        "conductor's (a warning instead of a refusal)",
    )
    p.add_argument("--db", type=Path, default=Path("nod-sessions.sqlite"), help="session store")
    p.add_argument(
        "--participant",
        default=None,
        help="participant id stored with the session (default: the first of P01, P02, … with "
        "no session in --db); one with a complete session is refused without --again",
    )
    p.add_argument("--seed", type=SEED, default=None, help="seed of the sim participant (stored)")
    p.add_argument("--session", default=None, help="session id (default: a new UUID)")
    p.add_argument(
        "--order",
        default=None,
        metavar="O,O,...",
        help="O of each consensus trial, e.g. blue,red,red,blue,red or BRRBR (a participant's "
        "counterbalanced order: `nod study start`); default: the schedule's own; stored with "
        "the session, and a resumed session keeps its own",
    )
    p.add_argument(
        "--again",
        default=None,
        metavar="REASON",
        help="start a new session for a participant who already has a complete one; the "
        "reason is stored with it",
    )
    p.add_argument(
        "--resume",
        metavar="SESSION",
        default=None,
        help="go on with a stored session at its next trial (after a crash or an abort); the "
        "participant and seed are the session's own",
    )
    p.add_argument(
        "--clicks",
        default="prompt",
        help="the counter clicks the participant counted: 'prompt' (default: asked after each "
        "trial is stored), a number for every trial, or 'none' (not entered; `nod clicks` enters "
        "them later)",
    )
    p.add_argument("--wait-services", type=float, default=30.0, help="seconds to wait for peers")
    p.add_argument(
        "--console",
        default="auto",
        choices=("auto", "live", "lines", "off"),
        help="the operator's view: a live panel (a terminal), one line per step (a pipe), or "
        "none (default auto)",
    )
    p.add_argument(
        "--record",
        type=Path,
        default=None,
        metavar="DIR",
        help="record the session's keys to DIR/<session>.mcap (a `nod record` child, stopped "
        "at the session's end; linked to the session in the store)",
    )
    p.add_argument(
        "--study",
        type=Path,
        default=None,
        metavar="STUDY.toml",
        help="the study file this session belongs to (`nod study start` gives it): its name, "
        "consent version, allocation seed and pre-registration go into the session's provenance",
    )
    p.add_argument(
        "--policy",
        default=None,
        metavar="paper|adaptive|FILE.toml",
        help="the robot policy that chooses each trial's b*, gaze level and u_r inside the "
        "params file's [policy] envelope (docs/adaptive.md); its name and hash are stored with "
        "the session, its settings with each trial; default: the paper's robot, nothing sent",
    )
    add_options_arg(p)
    return p


def clicks_source(
    spec: str, read_line: Callable[[str], str] = input, target: int = 10
) -> Callable[[int], int | None]:
    """The operator's counter values, from the --clicks flag (`read_line` asks for 'prompt')."""
    if spec == "prompt":
        return functools.partial(ask_clicks, read_line=read_line, target=target)
    if spec == "none":
        return lambda _trial: None
    if spec.isdigit():
        return lambda _trial: int(spec)
    raise ValueError(f"--clicks must be a number, 'prompt' or 'none', got {spec!r}")


def main(argv: list[str] | None = None) -> int:
    """Run one session; exit 0 when every trial is stored."""
    args = build_parser().parse_args(argv)
    if args.rig_file is not None:
        try:
            flags = rig_file_flags(args.rig_file, explicit_connect=bool(args.connect))
        except RigFileError as exc:
            return fail("nod experiment", exc)
        args = build_parser().parse_args([*flags, *(sys.argv[1:] if argv is None else argv)])
    setup_logging(args.verbose)
    try:
        cfg, schedule = load_with_options(args.params, args.options)
        own_hash = params_hash(cfg)  # the rig's parameters, before this session's --order
        prov = make_provenance(package_version(), own_hash, args.params, args.rig_file,
                               study=args.study)
        console = make_console(args.console)
        clicks = clicks_source(args.clicks, console.read_line, cfg.protocol.target_clicks)
        store = Store(args.db)
    except (ValueError, OSError) as exc:
        return fail("nod experiment", exc)
    keys = key_space(cfg, schedule)  # the paper's two options, or a table of N boxes
    policy = None
    if args.policy is not None:
        try:
            if keys.n_options != 2:
                raise ValueError("a robot policy runs on the paper's two-option table only")
            policy = load_choice(args.policy, keys.cfg)
        except (ValueError, OSError) as exc:
            store.close()
            return fail("nod experiment", f"--policy: {exc}")
        prov = dataclasses.replace(prov, policy_file=policy.name, policy_sha256=policy.sha256)
    if args.resume is not None and (
        problem := resume_problem(store, args.resume, args.rig, keys.names)
    ):
        store.close()  # another rig's session, a complete one: refused, the store unchanged
        return fail("nod experiment", problem)
    try:
        keys = session_keys(keys, store, args.order, args.resume)
    except ValueError as exc:
        store.close()
        return fail("nod experiment", exc)
    if args.participant is None:
        args.participant = next_free_ids(store, 1)[0]
    problem = participant_problem(store, args.participant, args.again, args.resume)
    if problem is not None:
        store.close()
        return fail("nod experiment", problem)
    participant, seed, first = args.participant, args.seed, 1
    lost: tuple[int, int, int] | None = None
    resume_at: tuple[int, int] | None = None
    if args.resume is not None:
        try:
            point = prepare_resume(store, args.resume, len(keys.trials))
        except OSError as exc:
            store.close()
            return fail("nod experiment", exc)
        if point is None:  # every trial stored: marked complete, nothing to do
            store.close()
            return 0
        participant, seed, first = point.participant, point.seed, point.first
        lost, resume_at = point.lost, point.resume_at
    if args.resume is not None and (problem := policy_resume_problem(store, args.resume, policy)):
        store.close()
        return fail("nod experiment", problem)
    warn_of_interrupted(store, args.resume)
    try:
        node = Node(
            "experiment", Fabric.from_args(args), retry_s=math.inf, params_hash=own_hash
        )
    except (ValueError, OSError, ConnectionError) as exc:
        store.close()
        return fail("nod experiment", exc)
    claim = claim_the_rig(node)
    if claim is None:
        node.close()
        store.close()
        return 2
    params_check = ParamsCheck(node)
    hosts = HostsSeen()  # every service's host, from its heartbeats (the session's provenance)
    hosts.add("experiment", socket.gethostname())
    node.subscribe("rig/status", lambda status: hosts.add(status.service, status.host))
    conductor = Conductor(node, keys.cfg, store, clicks, console, resume_at=resume_at, keys=keys,
                          policy=policy)
    watch_rivals(claim, node, conductor.rig, console.note)
    # The devices' states first, then this conductor's liveliness: a safe stop they hold
    # because no conductor ran is stored before they clear it (see `hear_the_devices`).
    hear_the_devices(node, conductor.rig.heard_every_device, min(args.wait_services,
                                                                 HEAR_DEVICES_S))
    node.ready()
    session = args.resume or args.session or uuid.uuid4().hex[:12]
    recorder = None
    if args.record is not None:
        recorder = _start_recorder(args, session, prov)
        if recorder is None:
            node.close()
            store.close()
            return 2
        conductor.recording = (recorder.path, node.clock.now_ns())
    complete = False
    run_ns: int | None = None  # wall clock: this run's provenance row, once written
    try:
        conductor.wait_for_services(args.wait_services)
        mismatch = params_check.problem(own_hash, args.params)
        if mismatch is not None and not args.allow_params_mismatch:
            print(f"nod experiment: {mismatch}", file=sys.stderr)
            return 2
        if mismatch is not None:
            log.warning("%s (--allow-params-mismatch: running anyway)", mismatch)
        if args.resume is None:  # the order this session runs, and why it is another one
            record_order(store, session, participant, keys.order(), args.again, time.time_ns())
        log.info(
            "session %s (%s): all services alive; %d options %s, trials %d-%d",
            session, participant, keys.n_options, list(keys.names), first, len(keys.trials),
        )
        run_ns = time.time_ns()
        write_provenance(store, session, run_ns, prov)
        conductor.run_session(
            session, participant, seed, first, resume=args.resume is not None, lost=lost
        )
        complete = True
    except TimeoutError as exc:
        print(f"nod experiment: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        log.warning("session %s interrupted", session)
        # A stop mid-trial is on record as the operator's, not as a lost conductor.
        conductor.stop_mid_trial("the conductor was stopped (Ctrl-C or SIGTERM) mid-trial")
        return 130
    finally:
        if recorder is not None:
            code = recorder.stop()
            log.info("recording %s (recorder exit %s)", recorder.path, code)
        node.close()
        if run_ns is not None and (problem := finish_provenance(
                store, session, run_ns, time.time_ns(), hosts.hosts(),
                None if recorder is None else recorder.path)):
            log.warning("%s", problem)
        back_up(store)  # the session ended (complete, stopped or aborted): a copy of the store
        if not complete:  # interrupted, aborted, or never started: how to go on with it
            say_how_to_resume(store, build_parser(), args, session)
        store.close()
    log.info("session %s complete: %s", session, json.dumps(str(args.db)))
    return 0


def rig_file_flags(path: Path, explicit_connect: bool = False) -> list[str]:
    """The session flags and `--params` a rig file gives the conductor (RigFileError if bad).

    Built by the rig file's one builder (`session_flags`) for the control station, whose
    identity the conductor speaks with under rig.tls. They go before the command line's own, so
    a flag given there wins; an explicit `--connect` replaces the rig's router.
    """
    rig = load_rig(path)
    flags = session_flags(rig, Host(CONTROL, ()), service="experiment")
    if explicit_connect and "--connect" in flags:
        at = flags.index("--connect")
        del flags[at : at + 2]
    return flags + (["--params", str(rig.params)] if rig.params is not None else [])


def _start_recorder(
    args: argparse.Namespace, session: str, prov: Provenance
) -> RecorderProcess | None:
    """Start `nod record` for the session and wait until it listens; None (said why) if not."""
    try:
        args.record.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"nod experiment: cannot record to {args.record}: {exc}", file=sys.stderr)
        return None
    path = recording_path(args.record, session)
    recorder = RecorderProcess(recorder_command(args, path, session, metadata(prov, session)),
                               path)
    if not recorder.wait_ready(RECORDER_READY_S):
        recorder.stop(tail_s=0.0)
        print(f"nod experiment: the recorder did not start (writing {path}); see the log above",
              file=sys.stderr)
        return None
    log.info("recording the session to %s", path)
    return recorder


if __name__ == "__main__":
    raise SystemExit(main())
