"""`nod estop`: engage (or release) the emergency stop of a rig from any machine."""

from __future__ import annotations

import argparse
import getpass
import socket
import sys
import time

from services.core import messages as m
from services.core.cli import Parser
from services.core.clock import Clock
from services.core.keys import Keys
from services.core.session import add_zenoh_args, open_session, zenoh_config


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod estop`."""
    p = Parser(
        prog="nod estop",
        description="Publish an e-stop on nod/<rig>/safety/estop: the arm holds and the eyes go "
        "neutral until released with --release.",
    )
    add_zenoh_args(p)
    p.add_argument("--release", action="store_true", help="release a latched e-stop")
    p.add_argument("--reason", default="operator", help="reason shown on the state keys")
    p.add_argument("--repeat", type=int, default=3, help="publish this many times, 50 ms apart")
    return p


def main(argv: list[str] | None = None) -> int:
    """Publish the e-stop (or its release) and exit."""
    args = build_parser().parse_args(argv)
    try:
        session = open_session(zenoh_config(args))
    except (ConnectionError, OSError) as exc:
        print(f"nod estop: {exc}", file=sys.stderr)
        return 2
    key = Keys(args.rig).topic("safety/estop")
    source = f"{getpass.getuser()}@{socket.gethostname()}"
    clock = Clock()
    try:
        pub = session.declare_publisher(key)
        time.sleep(0.2)  # let the route to the subscribers establish before the first put
        for i in range(max(1, args.repeat)):  # repeated: a single sample could be missed
            msg = m.Estop(
                seq=i,
                t_ns=clock.now_ns(),
                engaged=not args.release,
                reason=args.reason,
                source=source,
            )
            pub.put(m.encode(msg))
            time.sleep(0.05)
    finally:
        session.close()
    print(f"{'released' if args.release else 'ENGAGED'} e-stop on {key}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
