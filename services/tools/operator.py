"""`nod experiment next | pause | freeze`: the operator's commands, from any host of the rig.

`next` starts the trial that waits for the operator (`[protocol] gate = true`, or after a
pause) and waits until the conductor announces its setup on `experiment/trial` (one key space,
schema 3: one command for any option set); `pause`
holds the next trial until a `next`; `freeze` keeps the robot policy's last settings for the
rest of the session (`nod experiment --policy`), and succeeds only once the conductor confirms
it on `experiment/policy` (a session without a policy never does). Each command is sent once,
reliably, when the conductor listens: a repeat could start the trial after the one meant.
`--rig-file RIG.toml` takes the rig, its router (or, under rig.tls, the control station's
identity) from the rig file, as `nod experiment` does.
"""

from __future__ import annotations

import argparse
import getpass
import socket
import sys
import threading
import time
from pathlib import Path

from services.core import messages as m
from services.core.cli import fabric_parser, fail, int_in, positive_float
from services.core.node import Node
from services.core.rigfile import CONTROL, Host, RigFileError, load_rig, session_flags
from services.core.session import Fabric

PROG = "nod experiment"


def build_parser(action: str) -> argparse.ArgumentParser:
    """The command line of `nod experiment next` or `pause`."""
    what = {
        "next": "Start the trial that waits for the operator; waits until it is set up.",
        "pause": "Hold the next trial until `nod experiment next` (the current one goes on).",
        "freeze": "Keep the robot policy's last settings for the rest of the session.",
    }[action]
    p = fabric_parser(f"{PROG} {action}", what)
    p.add_argument("--rig-file", type=Path, default=None, metavar="RIG.toml",
                   help="take the rig name and its router (or identity) from a rig file")
    if action == "next":
        p.add_argument("--trial", type=int_in(0, 10_000), default=0,
                       help="the trial to start (default 0: whichever waits)")
    p.add_argument("--timeout", type=positive_float, default=10.0,
                   help="seconds to wait for the conductor (10)")
    return p


def rig_file_flags(path: Path, explicit: bool = False) -> list[str]:
    """The session flags a rig file gives the operator's command (RigFileError if bad).

    The control station's, as the conductor's (`session_flags`): under rig.tls its identity,
    which may publish experiment/operator. They go before the command line's own, so a flag
    given there wins; an explicit `--connect` or `--config` replaces the rig file's way in.
    """
    flags = session_flags(load_rig(path), Host(CONTROL, ()), service="operator")
    return flags[2:] if explicit else flags  # ["--connect" | "--config", X, "--rig", RIG]


def main(argv: list[str]) -> int:
    """Send one operator command; 0 when the conductor took it, 1 when it did not in time."""
    action = argv[0]
    args = build_parser(action).parse_args(argv[1:])
    prog = f"{PROG} {action}"
    if args.rig_file is not None:
        try:
            flags = rig_file_flags(args.rig_file, explicit=bool(args.connect or args.config))
        except RigFileError as exc:
            return fail(prog, exc)
        args = build_parser(action).parse_args([*flags, *argv[1:]])
    try:
        node = Node("operator", Fabric.from_args(args))
    except (ConnectionError, OSError, ValueError) as exc:
        return fail(prog, exc)
    try:
        if not node.peer_alive("experiment"):
            return fail(prog, f"no conductor is running on rig {node.keys.rig!r}")
        started = threading.Event()
        trial = getattr(args, "trial", 0)

        def on_trial(ev: m.TrialEvent) -> None:
            if ev.phase == "setup" and trial in (0, ev.trial):
                started.set()

        def on_policy(msg: m.PolicyMsg) -> None:
            if msg.frozen and action == "freeze":
                started.set()

        node.subscribe("experiment/trial", on_trial)
        if action == "freeze":
            node.subscribe("experiment/policy", on_policy)
        pub = node.publisher("experiment/operator")
        deadline = time.monotonic() + args.timeout
        while not pub.matched() and time.monotonic() < deadline:
            time.sleep(0.01)
        if not pub.matched():
            return fail(prog, "the conductor did not subscribe in time")
        source = f"{getpass.getuser()}@{socket.gethostname()}"
        pub.put(action="start" if action == "next" else action, trial=trial, source=source)
        if action == "pause":
            print(f"{prog}: sent; the next trial waits for `nod experiment next`")
            return 0
        if started.wait(max(0.0, deadline - time.monotonic())):
            print(f"{prog}: " + ("the trial is set up" if action == "next" else
                                 "the policy is frozen: its last settings hold"))
            return 0
        if action == "freeze":
            print(f"{prog}: the conductor did not confirm a freeze within {args.timeout:g} s "
                  "(does the session run a policy, `nod experiment --policy`? a freeze "
                  "before its first trial is confirmed when that trial is chosen)",
                  file=sys.stderr)
            return 1
        print(f"{prog}: no trial started within {args.timeout:g} s (does one wait for the "
              "operator? the conductor starts it once the rig is safe)", file=sys.stderr)
        return 1
    finally:
        node.close()
