"""`nod estop`: engage (or release) the emergency stop of a rig, and wait until every device obeys.

The command goes out with the contract's safety QoS (reliable, real-time priority) and a fresh
id; each device acknowledges it on its state key (`estop_id`, `estop`). `nod estop` repeats the
command until every expected device has acknowledged (or `--timeout` passes), prints who obeyed
and how fast, and exits 0 only if all did: with nobody listening it says so and fails, and a
device that heard it but did not acknowledge (its latch could not be saved) is named with the
reason its state key shows.

Ids carry their issue order (`services.model.latch`): an engage is ordered by this host's wall
clock; a release first asks the devices' latches (`safety/latch`) and is ordered above the
highest command any of them obeyed, so a host whose clock is behind can still release, while a
release issued earlier (replayed from a recording) never can.
"""

from __future__ import annotations

import argparse
import getpass
import socket
import sys
import threading
import time

from services.core.cli import fabric_parser, fail
from services.core.node import Node
from services.core.session import Fabric
from services.model.latch import new_command_id

DEVICES = ("actuation", "eyes")
ASK_LATCHES_S = 0.5  # how long a release waits for the devices' latches (it ends when all answer)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod estop`."""
    p = fabric_parser(
        "nod estop",
        "Engage the e-stop of a rig (the arm holds, the eyes go neutral) until it is "
        "released with --release; waits for every device to acknowledge.",
    )
    p.add_argument("--release", action="store_true", help="release a latched e-stop")
    p.add_argument("--reason", default="operator", help="reason shown on the state keys")
    p.add_argument(
        "--timeout", type=float, default=1.0, help="seconds to wait for acknowledgements (1)"
    )
    p.add_argument(
        "--devices",
        default=",".join(DEVICES),
        help=f"devices that must acknowledge, comma separated (default {','.join(DEVICES)})",
    )
    return p


class Acks:
    """Collects the devices' acknowledgements of one e-stop command."""

    def __init__(self, command_id: str, engaged: bool, t0: float) -> None:
        self.command_id = command_id
        self.engaged = engaged
        self.t0 = t0
        self.lock = threading.Lock()
        self.obeyed: dict[str, tuple[float, str]] = {}  # device → (seconds, reason shown)
        self.last_reason: dict[str, str] = {}  # device → the reason its last state showed
        self.done = threading.Event()
        self.expected: tuple[str, ...] = ()

    def state(self, device: str, estop_id: str, estop: bool, reason: str) -> None:
        """Record a device's state message if it acknowledges our command."""
        with self.lock:
            self.last_reason[device] = reason
        if estop_id != self.command_id or estop != self.engaged:
            return
        with self.lock:
            if device not in self.obeyed:
                self.obeyed[device] = (time.monotonic() - self.t0, reason)
            if all(d in self.obeyed for d in self.expected):
                self.done.set()


def main(argv: list[str] | None = None) -> int:
    """Publish the e-stop (or its release); exit 0 when every device acknowledged it."""
    args = build_parser().parse_args(argv)
    expected = tuple(d for d in args.devices.split(",") if d)
    if not expected or any(d not in DEVICES for d in expected):
        return fail("nod estop", f"--devices must name some of {', '.join(DEVICES)}")
    if not 0 < args.timeout <= 60:
        return fail("nod estop", f"--timeout must be in (0, 60] s, got {args.timeout}")
    try:
        node = Node("estop", Fabric.from_args(args))
    except (ConnectionError, OSError, ValueError) as exc:
        return fail("nod estop", exc)
    engaged = not args.release
    source = f"{getpass.getuser()}@{socket.gethostname()}"
    try:
        order = time.time_ns()
        if not engaged:  # above every command the devices obeyed (a clock behind theirs)
            floors = [latch.floor for latch in node.ask("safety/latch", ASK_LATCHES_S)]
            order = max(order, max(floors, default=0) + 1)
        acks = Acks(new_command_id(order), engaged, time.monotonic())
        acks.expected = expected
        node.subscribe(
            "actuation/state",
            lambda s: acks.state("actuation", s.estop_id, s.estop, s.safety_reason),
        )
        node.subscribe(
            "eyes/state", lambda s: acks.state("eyes", s.estop_id, s.estop, s.safety_reason)
        )
        # The contract's QoS: reliable, real-time priority. Engage and release have keys of their
        # own, so a lab's ACL can let every host engage and only the control station release.
        pub = node.publisher("safety/estop" if engaged else "safety/release")
        deadline = acks.t0 + args.timeout
        while not acks.done.is_set() and time.monotonic() < deadline:
            # Repeated until acknowledged: a device that joins late, or a sample that raced the
            # route being set up, still gets it. Devices treat repeats of one id as one command.
            pub.put(engaged=engaged, reason=args.reason, source=source, id=acks.command_id)
            acks.done.wait(0.05)
        alive = {d for d in expected if node.peer_alive(d)}
    finally:
        node.close()
    return _report(acks, expected, alive, engaged, args.rig, pub_key=f"nod/{args.rig}")


def _report(
    acks: Acks, expected: tuple[str, ...], alive: set[str], engaged: bool, rig: str, pub_key: str
) -> int:
    what = "ENGAGED" if engaged else "released"
    failed = False
    for device in expected:
        if device in acks.obeyed:
            seconds, reason = acks.obeyed[device]
            shown = f" ({reason})" if reason else ""
            print(f"{device}: obeyed in {seconds * 1e3:.0f} ms{shown}")
        elif device in alive:
            shown = acks.last_reason.get(device, "")
            why = f": {shown}" if shown else ""
            print(f"{device}: alive but did NOT acknowledge within the timeout{why}",
                  file=sys.stderr)
            failed = True
        else:
            print(f"{device}: not running on rig {rig!r} (no liveliness)", file=sys.stderr)
            failed = True
    verdict = "by every device" if not failed else "NOT by every device"
    print(f"e-stop {what} on {pub_key}, acknowledged {verdict}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
