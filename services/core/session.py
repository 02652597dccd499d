"""One way for every service to open its Zenoh session, like the zenoh-python examples.

`add_zenoh_args(parser)` adds `--mode/--connect/--listen/--config/--rig`; `zenoh_config(args)`
builds the `zenoh.Config`. Multicast scouting is off unless a config file turns it on: a lab
network decides its topology explicitly (and tests must never find each other by accident).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import zenoh

from services.core.keys import check_rig

DEFAULT_ROUTER = "tcp/127.0.0.1:7447"


def add_zenoh_args(parser: argparse.ArgumentParser, *, default_mode: str = "client") -> None:
    """Add the shared session flags to a service's argument parser."""
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
    g.add_argument("--rig", type=check_rig, default="rig1", help="rig name scoping every key")


def zenoh_config(args: argparse.Namespace) -> zenoh.Config:
    """Build the session configuration from the shared flags."""
    return make_config(
        mode=args.mode, connect=args.connect, listen=args.listen, config_file=args.config
    )


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
    _insert(conf, "mode", mode)
    if connect is None and mode == "client" and config_file is None:
        connect = [DEFAULT_ROUTER]
    if connect:
        _insert(conf, "connect/endpoints", connect)
    if listen:
        _insert(conf, "listen/endpoints", listen)
    return conf


def _insert(conf: zenoh.Config, key: str, value: Any) -> None:
    conf.insert_json5(key, json.dumps(value))


def open_session(conf: zenoh.Config) -> zenoh.Session:
    """Open a session, turning zenoh's connection error into one line that says what to do."""
    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        raise ConnectionError(
            f"cannot open the zenoh session ({exc}); is a router running at the --connect "
            "endpoint (e.g. `nod run`, or `nod router`)?"
        ) from None
