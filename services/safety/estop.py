"""`nod estop`: engage (or release) the emergency stop of a rig from any machine."""

from __future__ import annotations

import argparse
import getpass
import socket
import sys
import time

from services.core.cli import Parser
from services.core.node import Node
from services.core.session import Fabric, add_zenoh_args


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
        node = Node("estop", Fabric.from_args(args))
    except (ConnectionError, OSError, ValueError) as exc:
        print(f"nod estop: {exc}", file=sys.stderr)
        return 2
    source = f"{getpass.getuser()}@{socket.gethostname()}"
    try:
        pub = node.publisher("safety/estop")  # the contract's QoS: reliable, real-time priority
        time.sleep(0.2)  # let the route to the subscribers establish before the first put
        for _ in range(max(1, args.repeat)):  # repeated: a single sample could be missed
            pub.put(engaged=not args.release, reason=args.reason, source=source)
            time.sleep(0.05)
    finally:
        node.close()
    print(f"{'released' if args.release else 'ENGAGED'} e-stop on {pub.key}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
