"""`nod router`: a Zenoh router in a process of its own, for a lab's control station.

Equivalent to running `zenohd` with the same endpoints; provided so a lab needs nothing but this
package. Every service (`--mode client --connect <this endpoint>`) and any Zenoh tool can meet here.
"""

from __future__ import annotations

import threading
from pathlib import Path

from services.core.cli import Parser, fail
from services.core.node import install_signal_handlers
from services.core.session import DEFAULT_ROUTER, make_config, open_session


def main(argv: list[str] | None = None) -> int:
    """Run a router until SIGINT/SIGTERM."""
    p = Parser(prog="nod router", description=__doc__.splitlines()[0])
    p.add_argument(
        "-l",
        "--listen",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help=f"endpoint to listen on, repeatable (default {DEFAULT_ROUTER})",
    )
    p.add_argument("--config", type=Path, default=None, help="a zenoh JSON5 configuration file")
    args = p.parse_args(argv)
    listen = args.listen or ([DEFAULT_ROUTER] if args.config is None else None)
    try:
        session = open_session(make_config(mode="router", listen=listen, config_file=args.config))
    except (ConnectionError, OSError) as exc:
        return fail("nod router", exc)
    stop = threading.Event()
    install_signal_handlers(stop)
    print(f"nod router: listening on {', '.join(listen or ['(from config)'])}", flush=True)
    stop.wait()
    session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
