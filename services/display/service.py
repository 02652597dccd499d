"""`nod display`: the participant's screen — countdown, go and points — as a web page on the rig.

It follows the conductor's `experiment/trial` and `experiment/result` events (one key space,
schema 3: the same for any number of options, and nothing shown names one) and its
liveliness (`services.display.screen` decides what may be shown) and serves the page and its
Server-Sent Events stream (`services.display.web`) on `--http HOST:PORT`, for a browser in
kiosk mode:

    chromium --kiosk --noerrdialogs --no-first-run --app=http://127.0.0.1:8090/

When the conductor is gone the page says "Please wait"; so it does when the display service
itself is gone (the page's stream falls silent). Like the speaker, the display is a complement:
the conductor never waits for it.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import threading

from services.core import messages as m
from services.core.cli import fail, host_port, service_parser
from services.core.node import Node, setup_logging
from services.core.session import Fabric
from services.display.screen import DisplayState
from services.display.web import DisplayServer, ScreenFeed, load_static

log = logging.getLogger("nod.display")
DEFAULT_HTTP = "127.0.0.1:8090"


class DisplayService:
    """The screen state, fed by the conductor, published to the page's streams."""

    def __init__(self, node: Node, feed: ScreenFeed) -> None:
        self.state = DisplayState()
        self.feed = feed
        node.subscribe("experiment/trial", self.on_trial)
        node.subscribe("experiment/result", self.on_result)
        node.watch_liveliness("experiment", self.on_conductor)

    def _changed(self, changed: bool) -> None:
        if changed:
            screen = self.state.screen
            log.info("display: %s %r %r", screen.kind, screen.big, screen.small)
            self.feed.publish(screen.as_json(self.state.version))

    def on_trial(self, msg: m.TrialEvent) -> None:
        """A protocol event (ValueError: refused and counted by the node)."""
        self._changed(self.state.on_trial(msg))

    def on_result(self, msg: m.TrialResult) -> None:
        """A trial's result."""
        self._changed(self.state.on_result(msg))

    def on_conductor(self, alive: bool) -> None:
        """The conductor's liveliness token came or went."""
        log.info("display: the conductor is %s", "up" if alive else "gone")
        self._changed(self.state.on_conductor(alive))


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod display`."""
    p = service_parser(
        "nod display",
        "Serve the participant's screen (countdown, go, points) as a web page for "
        "a browser in kiosk mode, following the conductor's events.",
    )
    p.add_argument("--http", default=DEFAULT_HTTP, metavar="HOST:PORT",
                   help=f"where the page is served (default {DEFAULT_HTTP}; port 0: any free "
                   "one, printed at start; 0.0.0.0 for a screen on another machine)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the display until SIGINT/SIGTERM."""
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    setup_logging(args.verbose)
    try:
        address = host_port(args.http)
    except ValueError as exc:
        return fail("nod display", f"--http: {exc}")
    try:
        files = load_static()
        fabric = Fabric.from_args(args)
    except (ValueError, OSError) as exc:
        return fail("nod display", exc)
    feed = ScreenFeed(DisplayState().screen.as_json(0))
    try:  # before the session: a port in use fails at once, with nothing to undo
        server = DisplayServer(address, feed, files)
    except OSError as exc:
        return fail("nod display", f"cannot serve on {args.http}: {exc.strerror or exc}")
    host = f"[{address[0]}]" if ":" in address[0] else address[0]
    url = f"http://{host}:{server.port}/"
    threading.Thread(target=server.serve_forever, name="http", daemon=True).start()
    try:
        node = Node("display", fabric, retry_s=math.inf)
    except (ValueError, OSError, ConnectionError) as exc:
        server.shutdown()
        return fail("nod display", exc)
    log.info("display: the participant's page is on %s", url)
    print(f"nod display: serving {url}", flush=True)
    DisplayService(node, feed)
    try:
        node.run()
    finally:
        feed.close()
        server.shutdown()
        server.server_close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
