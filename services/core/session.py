"""One way for every service to open its Zenoh session, like the zenoh-python examples.

`Fabric` is a service's place on the network as typed config: the rig, the session (mode,
endpoints, config file) and the shared simulated clock. `add_zenoh_args(parser)` adds
`--mode/--connect/--listen/--config/--rig` and `Fabric.from_args` reads them (with the clock
flags); tests build a `Fabric` directly. Multicast scouting is off unless a config file turns it
on: a lab network decides its topology explicitly (and tests must never find each other by
accident).

Every session — service, tool or `nod router`, with or without a config file — gets the rig's
intake bounds on top of its configuration (`harden`): the contract's size limit per key
(`services.core.limits`: zenoh's low-pass filter drops a bigger message in the router and in
the receiving session, before it reaches a subscriber), and no shared memory.
"""

from __future__ import annotations

import argparse
import json
import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import zenoh

from services.core.clock import Clock
from services.core.keys import check_rig
from services.core.limits import low_pass_filters
from services.core.text import one_line

DEFAULT_ROUTER = "tcp/127.0.0.1:7447"
# The transport refuses larger messages (zenoh's default is 1 GiB): no message of the rig comes
# near it (a monitor frame is ≤ 260 kB), and an oversized one would stay resident in every host.
MAX_MESSAGE_BYTES = 1 << 20
# zenoh's implicit shared-memory transport (on by default) puts every message of 3 kB or more
# from a process on the same host into a 16 MiB pool of that sender's; each receiver maps the
# pools it is sent from and keeps them mapped for good: a burst from four local senders left
# the router and a service ~180 MB larger, and every restart of a local sender adds its pool.
# No message of the rig needs it (the largest is a 260 kB frame at 30 Hz). Refused when either
# end disables it.
SHARED_MEMORY = False
log = logging.getLogger(__name__)


def add_zenoh_args(
    parser: argparse.ArgumentParser, *, default_mode: str = "client", rig: bool = True
) -> None:
    """Add the shared session flags to a service's argument parser (`rig`: with --rig)."""
    g = parser.add_argument_group("zenoh session")
    g.add_argument(
        "--mode",
        choices=("client", "peer", "router"),
        default=default_mode,
        help=f"zenoh session mode (default: {default_mode})",
    )
    g.add_argument(
        "-e",
        "--connect",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help=f"endpoint to connect to, repeatable (default for clients: {DEFAULT_ROUTER})",
    )
    g.add_argument(
        "-l", "--listen", action="append", default=None, metavar="ENDPOINT", help="listen endpoint"
    )
    g.add_argument("--config", type=Path, default=None, help="a zenoh JSON5 configuration file")
    if rig:  # a tool of every rig at once (`nod lab status`) has none
        g.add_argument("--rig", type=check_rig, default="rig1", help="rig name scoping every key")


@dataclass(frozen=True, slots=True)
class Fabric:
    """Where a service meets the others: its rig, its zenoh session and the shared clock."""

    rig: str = "rig1"  # scopes every key: nod/<rig>/...
    mode: Literal["client", "peer", "router"] = "client"
    connect: tuple[str, ...] = ()  # endpoints; a client with none connects to DEFAULT_ROUTER
    listen: tuple[str, ...] = ()
    config_file: Path | None = None  # a zenoh JSON5 file (TLS, ACL, ...); flags go on top
    speed: float = 1.0  # simulated seconds per wall second (simulation only)
    epoch_ns: int | None = None  # start of the shared simulated clock (set by `nod run`)

    def __post_init__(self) -> None:
        check_rig(self.rig)
        if self.mode not in ("client", "peer", "router"):
            raise ValueError(f"mode must be client, peer or router, got {self.mode!r}")

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Fabric:
        """The fabric the shared flags describe (clock flags optional)."""
        return cls(
            rig=getattr(args, "rig", "rig1"),
            mode=args.mode,
            connect=tuple(args.connect or ()),
            listen=tuple(args.listen or ()),
            config_file=args.config,
            speed=getattr(args, "speed", 1.0),
            epoch_ns=getattr(args, "epoch_ns", None),
        )

    def zenoh_config(self) -> zenoh.Config:
        """The session configuration."""
        return make_config(
            mode=self.mode,
            connect=list(self.connect) or None,
            listen=list(self.listen) or None,
            config_file=self.config_file,
        )

    def clock(self) -> Clock:
        """The clock every message of this service is stamped with."""
        return Clock(self.speed, self.epoch_ns)


def make_config(
    *,
    mode: str = "client",
    connect: list[str] | None = None,
    listen: list[str] | None = None,
    config_file: Path | None = None,
) -> zenoh.Config:
    """Build a zenoh.Config: a file (if given), then explicit endpoints and mode on top."""
    if config_file is not None:
        if not Path(config_file).is_file():
            raise FileNotFoundError(f"zenoh config file not found: {config_file}")
        conf = zenoh.Config.from_file(str(config_file))
    else:
        conf = zenoh.Config()
        _insert(conf, "scouting/multicast/enabled", False)
        _insert(conf, "transport/link/rx/max_message_size", MAX_MESSAGE_BYTES)
    harden(conf)
    _insert(conf, "mode", mode)
    if connect is None and mode == "client" and config_file is None:
        connect = [DEFAULT_ROUTER]
    if connect:
        _insert(conf, "connect/endpoints", connect)
    if listen:
        _insert(conf, "listen/endpoints", listen)
    return conf


def harden(conf: zenoh.Config) -> None:
    """Put the rig's intake bounds on a configuration: per-key size limits, no shared memory.

    The contract's low-pass rules go after any the configuration already has (zenoh applies the
    smallest limit that matches a key, so a file can only tighten them).
    """
    rules = json.loads(conf.get_json("low_pass_filter") or "[]") or []
    _insert(conf, "low_pass_filter", [*rules, *low_pass_filters()])
    _insert(conf, "transport/shared_memory/enabled", SHARED_MEMORY)


def _insert(conf: zenoh.Config, key: str, value: Any) -> None:
    conf.insert_json5(key, json.dumps(value))


def open_session_retrying(
    fabric: Fabric, stop: threading.Event, who: str, retry_s: float | None
) -> zenoh.Session:
    """Open a session; while no router answers, retry with backoff (up to `retry_s`, or never).

    One line per attempt (0.2 s, doubling to 5 s apart). `stop` (a signal) ends the wait with a
    ConnectionError.
    """
    deadline = None if retry_s is None else time.monotonic() + retry_s
    delay = 0.2
    while True:
        try:
            return open_session(fabric.zenoh_config())
        except ConnectionError as exc:
            if deadline is None or time.monotonic() + delay > deadline or stop.is_set():
                raise
            where = ", ".join(fabric.connect) or DEFAULT_ROUTER
            log.warning("%s: no router at %s yet; retrying in %.1f s", who, where, delay)
            if stop.wait(delay):
                raise ConnectionError("stopped while waiting for the router") from exc
            delay = min(delay * 2, 5.0)


def open_session(conf: zenoh.Config) -> zenoh.Session:
    """Open a session, turning zenoh's connection error into one line that says what to do."""
    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        text = one_line(str(exc))
        if "Address already in use" in text or "AddrInUse" in text:
            hint = ("something already listens there (another `nod run`, `nod up` or router?): "
                    "stop it, or listen on another endpoint")
        elif "listener" in text.lower():
            hint = "check the --listen endpoint (an address of this host, a free port)"
        else:
            hint = ("is a router running at the --connect endpoint (e.g. `nod run`, or "
                    "`nod router`)?")
        raise ConnectionError(f"cannot open the zenoh session ({text}); {hint}") from None
