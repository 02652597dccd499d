"""`nod up RIG.toml`: start this host's part of a rig (or the whole rig) under supervision.

    nod up rig.toml --host arm        # on the arm controller: its services, as the file says
    nod up rig.toml                   # every host's services on this machine
    nod up rig.toml --sim-hardware    # the same with simulated arm, eyes and participant
    nod up rig.toml --host arm --exec actuation   # exec one service (systemd supervises)
    nod up rig.toml --host arm --dry-run          # the preflight: commands, files, ports, cameras
    nod up deploy/rig.example.toml --init-rig /etc/nod   # copy a rig file with the files it names

With the router on this host (`router = true`, or the whole rig here) the router runs inside
this process. Every service is a child process under a `Supervisor`: restarted with backoff
when it dies, given up (and reported) when it keeps dying; each event is printed and published
on rig/event. Ctrl-C or SIGTERM stops everything cleanly (arm holds, eyes neutral) and exits 0;
a service given up on makes the exit code 1, and one the rig needs (decision, actuation, eyes,
vision or the sim standing in for it) stops the whole rig safely first. `nod status --connect
ROUTER` shows the rig.

In a secured lab (`rig.tls`) this process speaks as its host's launcher identity, the only one
the router lets publish rig/event (`services.lab.acl`), and each service as its own (the host's
role, the monitor's); on the router's host it is the router itself (a rig router of its own
when `nod lab secure --router-per-rig` wrote one, linked to the lab router).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import threading
import time
from pathlib import Path

from services.core.cli import Parser, fail
from services.core.clock import Clock
from services.core.config import load_with_options
from services.core.keys import Keys
from services.core.lifeline import nod_command
from services.core.rigfile import (
    LAUNCHER,
    REQUIRED,
    Rig,
    RigFileError,
    identity,
    load_rig,
    router_config,
)
from services.core.session import make_config, open_session
from services.core.signals import on_stop_signal
from services.launch.commands import command
from services.launch.events import RigEvents
from services.launch.init_rig import init_rig
from services.launch.preflight import problems
from services.launch.supervisor import RestartPolicy, ServiceSpec, Supervisor
from services.launch.view import session_view

log = logging.getLogger("nod.up")


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod up`."""
    p = Parser(prog="nod up", description=__doc__.splitlines()[0])
    p.add_argument("rig_file", type=Path, metavar="RIG.toml", help="the rig file")
    p.add_argument("--host", default=None, help="run this host's services (default: all here)")
    p.add_argument(
        "--sim-hardware",
        action="store_true",
        help="simulate arm, eyes and the participant (no devices, no camera)",
    )
    p.add_argument(
        "--listen",
        default=None,
        help="router endpoint to listen on and connect to, overriding rig.router (e.g. to run a "
        "LAN rig file on one machine: tcp/127.0.0.1:7447); not with rig.tls",
    )
    p.add_argument("--logs", type=Path, default=None, help="folder for service logs")
    p.add_argument(
        "--exec",
        dest="exec_service",
        metavar="SERVICE",
        default=None,
        help="replace this process with one service of --host, or `router` (a systemd unit per "
        "service: systemd supervises it)",
    )
    p.add_argument("--max-restarts", type=int, default=5, help="per minute, before giving up (5)")
    p.add_argument(
        "--dry-run",
        action="store_true",
        help="print the commands and check every file, serial port and camera they need (one "
        "line per problem, exit 2); start nothing",
    )
    p.add_argument(
        "--init-rig",
        type=Path,
        default=None,
        metavar="DIR",
        help="copy RIG.toml to DIR/rig.toml with every file it names by a relative path (e.g. "
        "`nod up deploy/rig.example.toml --init-rig /etc/nod`); start nothing",
    )
    return p


def plan(rig: Rig, host: str | None) -> tuple[list[str], bool]:
    """The services to start here and whether this process runs the router."""
    if host is None:
        return list(rig.services), True  # the whole rig on one machine: router included
    if host not in rig.hosts:
        raise RigFileError(f"{rig.path}: no host {host!r}; hosts: {', '.join(rig.hosts)}")
    h = rig.hosts[host]
    return list(h.services), h.router


def router_command(rig: Rig, listen: str | None = None) -> list[str]:
    """`nod router` as the rig file says: mutual TLS with rig.tls, else plain on rig.router."""
    if rig.tls is not None and listen is None:
        return nod_command("router", "--config", str(router_config(rig.tls)))
    return nod_command("router", "--listen", listen or rig.router)


def router_listens(config: Path) -> str:
    """Where a `nod lab secure` router config listens (for the start-up line)."""
    try:
        text = config.read_text()
        doc = json.loads("\n".join(ln for ln in text.splitlines() if not ln.startswith("//")))
        return ", ".join(doc["listen"]["endpoints"])
    except (OSError, ValueError, KeyError, TypeError):
        return f"(as {config} says)"


def router_line(rig: Rig, with_router: bool, endpoint: str, listen: str | None = None) -> str:
    """Which router this start runs or reaches, in one line (`--dry-run` prints it first)."""
    if not with_router:
        owner = next((h.name for h in rig.hosts.values() if h.router), "the router's host")
        return f"router: at {endpoint} (run by {owner}, not here)"
    if rig.tls is not None and listen is None:
        config = router_config(rig.tls)
        return f"router: in this process, mutual TLS as {config}, on {router_listens(config)}"
    return f"router: in this process, listening on {endpoint}"


def sim_swaps(rig: Rig, services: list[str]) -> str | None:
    """What `--sim-hardware` replaces here, in one line (None: nothing the rig file names).

    Every device becomes its simulation, the camera the sim participant — and a speaker that
    writes WAV files (`driver = "wav"`) goes silent too, which nobody would guess.
    """
    swaps = []
    for service in services:
        sec = rig.sections.get(service, {})
        if service in ("actuation", "eyes", "speaker") and sec.get("driver", "sim") != "sim":
            what = " (no WAV written)" if sec["driver"] == "wav" else ""
            swaps.append(f"{service} driver {sec['driver']!r} runs as 'sim'{what}")
        elif service == "vision":
            swaps.append("vision runs as the sim participant")
    return "--sim-hardware: " + "; ".join(swaps) if swaps else None


def main(argv: list[str] | None = None) -> int:
    """Start, supervise, stop."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    if args.init_rig is not None:
        try:
            print("\n".join(init_rig(args.rig_file, args.init_rig)))
        except RigFileError as exc:
            return fail("nod up", exc)
        return 0
    rig = None
    try:
        rig = load_rig(args.rig_file)
        services, with_router = plan(rig, args.host)
        load_with_options(rig.params)  # a bad params file is one line here, not five dead services
    except (RigFileError, ValueError, OSError) as exc:
        where = "" if rig is None or str(rig.params) in str(exc) else f"{rig.params}: "
        return fail("nod up", f"{where}{exc}")
    if args.listen and rig.tls is not None:
        # It would start a plain router while the services speak TLS to the one of rig.tls.
        return fail(
            "nod up",
            f"--listen runs a plain router, but {rig.path} has rig.tls: the "
            "secured router listens where `nod lab secure --rig-file` put it",
        )
    endpoint = args.listen or rig.router
    if args.exec_service == "router":
        if not with_router:
            return fail("nod up", "the router runs on the host with `router = true`")
        cmd = router_command(rig, endpoint if args.listen else None)
        os.execv(cmd[0], cmd)
    if args.exec_service is not None:
        if args.exec_service not in services:
            here = ", ".join(services)
            return fail("nod up", f"{args.exec_service!r} does not run here ({here})")
        cmd = command(rig, args.exec_service, sim_hardware=args.sim_hardware, connect=endpoint)
        os.execv(cmd[0], cmd)
    commands = {
        s: command(rig, s, sim_hardware=args.sim_hardware, connect=endpoint) for s in services
    }
    swapped = sim_swaps(rig, services) if args.sim_hardware else None
    if swapped:
        print(swapped, flush=True)
    if args.dry_run:
        print(router_line(rig, with_router, endpoint, args.listen), flush=True)
        for s, cmd in commands.items():
            print(f"{s}: {' '.join(cmd)}", flush=True)
        found = problems(
            rig, services, host=args.host, with_router=with_router, sim_hardware=args.sim_hardware
        )
        for line in found:
            print(f"nod up: {line}", file=sys.stderr)
        return 2 if found else 0
    logs = args.logs or Path(f"nod-{rig.name}.logs")
    try:
        logs.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return fail("nod up", f"cannot write logs to {logs}: {exc.strerror}")
    router = None
    try:
        tls = rig.tls
        if with_router and tls is not None:
            cfg = make_config(mode="router", config_file=router_config(tls))
            endpoint = router_listens(router_config(tls))
        elif with_router:
            cfg = make_config(mode="router", listen=[endpoint])
        elif tls is not None:  # the launcher's own identity: rig events, nothing else
            cfg = make_config(
                mode="client", config_file=identity(rig, LAUNCHER, rig.hosts[args.host])
            )
        else:
            cfg = make_config(mode="client", connect=[endpoint])
        session = router = open_session(cfg)
    except (ConnectionError, ValueError) as exc:
        what = "listen on" if with_router else "reach the router at"
        return fail("nod up", f"cannot {what} {endpoint}: {exc}")
    except Exception as exc:  # zenoh.ZError: a malformed endpoint
        return fail("nod up", f"bad endpoint {endpoint!r}: {exc}")
    keys = Keys(rig.name)
    events = RigEvents(session, keys, Clock())
    events.quiet_starts = False  # an operator starting a rig wants to see each service come up
    policy = RestartPolicy(max_restarts=max(0, args.max_restarts))
    supervisor = Supervisor(policy, on_event=events)
    stopping = threading.Event()
    on_stop_signal(lambda _signum: stopping.set())  # never set() inside a handler
    where = f"host {args.host}" if args.host else "every host, on this machine"
    router_note = f"router on {endpoint}" if with_router else f"router at {endpoint}"
    print(
        f"rig {rig.name!r} ({where}): {', '.join(services)}; {router_note}; logs in {logs}/",
        flush=True,
    )
    # The operator sees the session's trials here too, whoever runs the conductor.
    view = session_view(*load_with_options(rig.params))  # its trials and option names
    subs = view.subscribe(session, keys)
    reported: set[str] = set()
    try:
        for s in services:
            log_path = logs / f"{s}.log"
            supervisor.start(ServiceSpec(s, commands[s], log=log_path))
        while not stopping.is_set():
            supervisor.poll()
            for name in supervisor.failed():
                if name not in reported:
                    reported.add(name)
                    print(
                        f"nod up: {name} is down (given up); see {logs}/{name}.log",
                        file=sys.stderr,
                        flush=True,
                    )
            needed = sorted(n for n in reported if n in (*REQUIRED, "sim"))
            if needed:
                # Half a rig runs no trial, and what still runs would only hold and wait: stop it
                # all safely (the arm holds, the eyes go neutral) and say so.
                print(
                    f"nod up: {', '.join(needed)} gave up: a rig cannot run without it; "
                    "stopping every service",
                    file=sys.stderr,
                    flush=True,
                )
                break
            stopping.wait(0.1)
    finally:
        supervisor.stop()
        for sub in subs:
            sub.undeclare()
        time.sleep(0.05)  # let the last rig events leave before the session closes
        if router is not None:
            router.close()
    print("every service stopped", flush=True)
    return 1 if supervisor.failed() else 0


if __name__ == "__main__":
    raise SystemExit(main())
