"""The participant's page over HTTP: three shipped files and a Server-Sent Events stream.

A stdlib `ThreadingHTTPServer` (no web framework: four fixed GET routes, nothing to parse):

- `/`, `/display.js`, `/display.css`: the page, read once at start from the package
  (`services/display/static/`), served with a Content-Security-Policy that lets it load only
  from this server — nothing is fetched from anywhere else, ever;
- `/events`: `text/event-stream`; the current screen at once, each new screen as it comes,
  and the current one again every `KEEPALIVE_S`, so the page can tell a live stream from a
  dead one (it shows "please wait" after `display.js`'s STALE_MS of silence). The browser's
  EventSource reconnects by itself (`retry:` below); the page reopens it if it gives up.

A stream holds a thread; `MAX_STREAMS` of them at once (a kiosk needs one; a reload briefly two).
"""

from __future__ import annotations

import json
import logging
import socket
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any

log = logging.getLogger("nod.display")
KEEPALIVE_S = 1.0  # the page calls a stream stale after 3 s without a message
RETRY_MS = 1000  # the browser's reconnect delay after a lost stream
MAX_STREAMS = 8
STATIC = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/display.js": ("display.js", "text/javascript; charset=utf-8"),
    "/display.css": ("display.css", "text/css; charset=utf-8"),
}
SECURITY_HEADERS = {
    # Only this server's own files: no CDN, no inline script, no outside connection.
    "Content-Security-Policy": "default-src 'self'; base-uri 'none'; form-action 'none'",
    "X-Content-Type-Options": "nosniff",
    "Cache-Control": "no-store",
}


def load_static() -> dict[str, bytes]:
    """The page's files from the package; OSError names a missing one."""
    folder = resources.files("services.display") / "static"
    return {name: (folder / name).read_bytes() for name, _ in STATIC.values()}


class ScreenFeed:
    """The latest screen's payload; streams wait here for the next one."""

    def __init__(self, payload: dict[str, Any]) -> None:
        self._cond = threading.Condition()
        self._payload = payload
        self._version = 0
        self.closed = False

    def publish(self, payload: dict[str, Any]) -> None:
        """A new screen for every stream."""
        with self._cond:
            self._payload, self._version = payload, self._version + 1
            self._cond.notify_all()

    def latest(self) -> tuple[int, dict[str, Any]]:
        """(version, payload) of the current screen."""
        with self._cond:
            return self._version, self._payload

    def wait_newer(self, version: int, timeout_s: float) -> tuple[int, dict[str, Any]]:
        """The next screen after `version`, or the current one after `timeout_s` (a keep-alive)."""
        with self._cond:
            self._cond.wait_for(lambda: self._version != version or self.closed, timeout_s)
            return self._version, self._payload

    def close(self) -> None:
        """End every stream (the service stops)."""
        with self._cond:
            self.closed = True
            self._cond.notify_all()


class DisplayServer(ThreadingHTTPServer):
    """The page's server: its files, its feed, and a count of open streams."""

    daemon_threads = True  # a stream never holds the process up at exit
    allow_reuse_address = True

    def __init__(self, address: tuple[str, int], feed: ScreenFeed, files: dict[str, bytes]):
        if ":" in address[0]:  # an IPv6 literal
            self.address_family = socket.AF_INET6
        super().__init__(address, DisplayHandler)
        self.feed = feed
        self.files = files
        self.streams = threading.BoundedSemaphore(MAX_STREAMS)

    @property
    def port(self) -> int:
        """The bound port (the one the OS chose for port 0)."""
        return int(self.server_address[1])


class DisplayHandler(BaseHTTPRequestHandler):
    """GET of the page's files and its event stream; nothing else."""

    server: DisplayServer
    server_version = "nod-display"

    def log_message(self, format: str, *args: Any) -> None:
        """Requests at debug level: a kiosk reloading must not fill the service's log."""
        log.debug("display: %s %s", self.address_string(), format % args)

    def _headers(self, status: HTTPStatus, content_type: str, length: int | None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        for name, value in SECURITY_HEADERS.items():
            self.send_header(name, value)
        if length is not None:
            self.send_header("Content-Length", str(length))
        self.end_headers()

    def do_GET(self) -> None:
        """Serve a file or the stream; 404 for anything else."""
        path = self.path.split("?", 1)[0]
        if path == "/events":
            self._stream()
            return
        if path not in STATIC:
            body = b"not found\n"
            self._headers(HTTPStatus.NOT_FOUND, "text/plain; charset=utf-8", len(body))
            self.wfile.write(body)
            return
        name, content_type = STATIC[path]
        body = self.server.files[name]
        self._headers(HTTPStatus.OK, content_type, len(body))
        self.wfile.write(body)

    def _stream(self) -> None:
        if not self.server.streams.acquire(blocking=False):
            body = b"too many open streams\n"
            self._headers(HTTPStatus.SERVICE_UNAVAILABLE, "text/plain; charset=utf-8", len(body))
            self.wfile.write(body)
            return
        try:
            self._headers(HTTPStatus.OK, "text/event-stream", None)
            feed = self.server.feed
            version, payload = feed.latest()
            self._send(f"retry: {RETRY_MS}\n\n")
            while not feed.closed:
                self._send(f"data: {json.dumps(payload)}\n\n")
                version, payload = feed.wait_newer(version, KEEPALIVE_S)
        except (BrokenPipeError, ConnectionResetError):
            pass  # the page went away (a reload, a closed kiosk): its stream ends here
        finally:
            self.server.streams.release()

    def _send(self, text: str) -> None:
        self.wfile.write(text.encode())
        self.wfile.flush()
