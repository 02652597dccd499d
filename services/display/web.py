"""The participant's page over HTTP: three shipped files and a Server-Sent Events stream.

Four fixed GET routes, no web framework:

- `/`, `/display.js`, `/display.css`: the page, read once at start from the package
  (`services/display/static/`), served with a Content-Security-Policy that lets it load only
  from this server — nothing is fetched from anywhere else, ever;
- `/events`: `text/event-stream`; the current screen at once, each new screen as it comes,
  and the current one again every `KEEPALIVE_S`, so the page can tell a live stream from a
  dead one (it shows "please wait" after `display.js`'s STALE_MS of silence). The browser's
  EventSource reconnects by itself (`retry:` below); the page reopens it if it gives up.

The kiosk always gets its screen. Every connection is served by ONE thread (an asyncio loop,
`DisplayServer.serve_forever`), so no number of connections adds a thread, and each thing a
connection may hold is bounded and given up by the oldest first:

- a connection that has not finished its request's headers (`MAX_HEADER_BYTES`) is closed after
  `HEADER_TIMEOUT_S`; at most `MAX_PENDING` of them are held, and a new one closes the oldest —
  a browser sends its whole request at once, so the kiosk's request is never the oldest;
- at most `MAX_STREAMS` streams; a new stream is always served, and to make room the server
  drops a stream its client stopped reading, else the oldest one (`Admission`). The slot kept
  is the newest stream's: the kiosk is recognised as the page loaded last. That is what a lab
  expects of a kiosk: whoever just (re)started or reloaded the participant's browser sees the
  screen, without a token in its URL or an address to configure (a kiosk on another machine, a
  replaced kiosk PC or a DHCP lease change work as they are), and a forgotten tab or a stuck
  client can never lock the participant's screen out — it is the one that gives way. A live
  browser that was dropped reconnects by itself in `RETRY_MS` and is then the newest;
- a stream whose client stops reading is dropped once its unsent data waited `STALL_S` (the
  kernel's socket buffers full): it holds at most one screen in this process, never a queue.

Files are answered with `Connection: close`: nothing is kept open between requests.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import socket
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from http import HTTPStatus
from importlib import resources
from typing import Any

log = logging.getLogger("nod.display")
KEEPALIVE_S = 1.0  # the page calls a stream stale after 3 s without a message
RETRY_MS = 1000  # the browser's reconnect delay after a lost stream
MAX_STREAMS = 16  # a kiosk needs one, a reload briefly two; the rest: an experimenter's tabs
MAX_PENDING = 256  # connections still sending their request's headers
HEADER_TIMEOUT_S = 5.0  # a browser sends its headers in milliseconds; generous for a loaded host
MAX_HEADER_BYTES = 8192  # a request line and headers; a browser's are well under 2 KB
STALL_S = 10.0  # a stream's unsent screen waited this long: its client stopped reading
BACKLOG = 128  # the listening socket's queue: a burst of connections waits here, not refused
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
SERVER_NAME = "nod-display"


def load_static() -> dict[str, bytes]:
    """The page's files from the package; OSError names a missing one."""
    folder = resources.files("services.display") / "static"
    return {name: (folder / name).read_bytes() for name, _ in STATIC.values()}


# --- pure parts: the request, the response's head, who gives way ----------------------------


@dataclass(frozen=True, slots=True)
class Request:
    """A request's method and path (its query and headers are of no use here)."""

    method: str
    path: str


def parse_request(head: bytes) -> Request:
    """The request line of a request's head (up to its blank line); ValueError if malformed."""
    line = head.split(b"\n", 1)[0].rstrip(b"\r")
    try:
        method, target, version = line.decode("ascii").split(" ")
    except (UnicodeDecodeError, ValueError):
        raise ValueError(f"not an HTTP request line: {line[:80]!r}") from None
    if not version.startswith("HTTP/1.") or not method.isalpha() or not target.startswith("/"):
        raise ValueError(f"not an HTTP/1.x request line: {line[:80]!r}")
    return Request(method.upper(), target.split("?", 1)[0].split("#", 1)[0])


def response_head(status: HTTPStatus, content_type: str, length: int | None) -> bytes:
    """A response's status line and headers; no length: the body runs to the connection's end."""
    lines = [f"HTTP/1.1 {status.value} {status.phrase}", f"Server: {SERVER_NAME}",
             f"Content-Type: {content_type}", *(f"{k}: {v}" for k, v in SECURITY_HEADERS.items())]
    if length is not None:
        lines.append(f"Content-Length: {length}")
    lines.append("Connection: close")
    return ("\r\n".join(lines) + "\r\n\r\n").encode("ascii")


def route(request: Request, files: dict[str, bytes]) -> tuple[HTTPStatus, str, bytes] | None:
    """(status, content type, body) of a file or an error; None: the event stream."""
    if request.method != "GET":
        return HTTPStatus.METHOD_NOT_ALLOWED, "text/plain; charset=utf-8", b"GET only\n"
    if request.path == "/events":
        return None
    if request.path not in STATIC:
        return HTTPStatus.NOT_FOUND, "text/plain; charset=utf-8", b"not found\n"
    name, content_type = STATIC[request.path]
    return HTTPStatus.OK, content_type, files[name]


class Admission:
    """Who holds a place: connections still sending headers, and open streams, oldest first.

    `pending`/`stream` admit a newcomer ALWAYS and return who must give way for it: the oldest
    pending connection beyond `max_pending`; for a stream, one whose client stopped reading,
    else the oldest, beyond `max_streams`. Pure bookkeeping: the server closes the ones named.
    """

    def __init__(self, max_pending: int = MAX_PENDING, max_streams: int = MAX_STREAMS) -> None:
        if max_pending < 1 or max_streams < 1:
            raise ValueError("Admission: at least one pending connection and one stream")
        self.max_pending, self.max_streams = max_pending, max_streams
        self._pending: OrderedDict[Hashable, None] = OrderedDict()
        self._streams: OrderedDict[Hashable, bool] = OrderedDict()  # → its client stopped reading

    @property
    def counts(self) -> tuple[int, int]:
        """(pending connections, streams) held now."""
        return len(self._pending), len(self._streams)

    def pending(self, conn: Hashable) -> list[Hashable]:
        """A new connection; the ones to close for it (the oldest beyond the bound)."""
        self._pending[conn] = None
        out = []
        while len(self._pending) > self.max_pending:
            out.append(self._pending.popitem(last=False)[0])
        return out

    def stream(self, conn: Hashable) -> list[Hashable]:
        """`conn` (pending or not) becomes a stream; the streams to close for it."""
        self._pending.pop(conn, None)
        self._streams[conn] = False
        out = []
        while len(self._streams) > self.max_streams:
            victim = next((c for c, stuck in self._streams.items() if stuck and c != conn),
                          next(iter(self._streams)))
            del self._streams[victim]
            out.append(victim)
        return out

    def stalled(self, conn: Hashable, stuck: bool) -> None:
        """A stream's client stopped reading (`stuck`), or reads again."""
        if conn in self._streams:
            self._streams[conn] = stuck

    def done(self, conn: Hashable) -> None:
        """`conn` closed: its place is free (pending or stream; unknown: nothing)."""
        self._pending.pop(conn, None)
        self._streams.pop(conn, None)


# --- the feed: screens from the service's (Zenoh) threads to the loop -----------------------


class ScreenFeed:
    """The latest screen's payload; the server hears of each new one (thread-safe)."""

    def __init__(self, payload: dict[str, Any]) -> None:
        self._lock = threading.Lock()
        self._payload = payload
        self._version = 0
        self._listeners: list[Callable[[], None]] = []
        self.closed = False

    def listen(self, callback: Callable[[], None]) -> None:
        """Call `callback()` (from the publishing thread) on each new screen and on close."""
        with self._lock:
            self._listeners.append(callback)

    def _tell(self) -> None:
        with self._lock:
            listeners = list(self._listeners)
        for callback in listeners:
            callback()

    def publish(self, payload: dict[str, Any]) -> None:
        """A new screen for every stream."""
        with self._lock:
            self._payload, self._version = payload, self._version + 1
        self._tell()

    def latest(self) -> tuple[int, dict[str, Any]]:
        """(version, payload) of the current screen."""
        with self._lock:
            return self._version, self._payload

    def close(self) -> None:
        """End every stream (the service stops)."""
        with self._lock:
            self.closed = True
        self._tell()


# --- the server: one thread, one loop -------------------------------------------------------


class DisplayServer:
    """The page's server: its files, its feed, the bounded places of its connections.

    The constructor binds (a port in use fails there, at once); `serve_forever` runs the loop in
    the calling thread until `shutdown` (from any thread); `server_close` frees the port.
    """

    def __init__(self, address: tuple[str, int], feed: ScreenFeed, files: dict[str, bytes],
                 admission: Admission | None = None) -> None:
        family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        self.socket = socket.create_server(address, family=family, backlog=BACKLOG)
        self.feed = feed
        self.files = files
        self.admission = admission or Admission()
        self.dropped = 0  # connections closed to make room for newer ones
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._tick: asyncio.Event | None = None
        self._tasks: dict[int, asyncio.Task[None]] = {}
        self._next_id = 0
        self._closing = threading.Event()  # shutdown() was called
        self._running = threading.Event()  # serve_forever() was entered
        self._finished = threading.Event()
        feed.listen(self._wake_threadsafe)

    @property
    def port(self) -> int:
        """The bound port (the one the OS chose for port 0)."""
        return int(self.socket.getsockname()[1])

    def serve_forever(self) -> None:
        """Serve until `shutdown`."""
        self._running.set()
        try:
            asyncio.run(self._serve())
        finally:
            self._finished.set()

    def shutdown(self) -> None:
        """Stop `serve_forever` and wait for it (at once if it never ran)."""
        self._closing.set()
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None:
            with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                loop.call_soon_threadsafe(stop.set)
        if self._running.is_set():
            self._finished.wait(10)

    def server_close(self) -> None:
        """Free the port."""
        self.socket.close()

    # -- inside the loop --

    async def _serve(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop, self._tick = asyncio.Event(), asyncio.Event()
        if self._closing.is_set():  # shutdown() came before the loop ran
            return
        server = await asyncio.start_server(self._connection, sock=self.socket,
                                            limit=MAX_HEADER_BYTES, backlog=BACKLOG)
        try:
            await self._stop.wait()
        finally:
            server.close()
            for task in list(self._tasks.values()):
                task.cancel()
            await asyncio.gather(*self._tasks.values(), return_exceptions=True)

    def _wake_threadsafe(self) -> None:
        loop = self._loop
        if loop is not None:
            with contextlib.suppress(RuntimeError):  # the loop is closed: nobody to tell
                loop.call_soon_threadsafe(self._wake)

    def _wake(self) -> None:
        """A new screen (or the end): every waiting stream wakes; later waits get a new event."""
        if self._tick is not None:
            tick, self._tick = self._tick, asyncio.Event()
            tick.set()

    def _drop(self, conns: list[Any], why: str, level: int = logging.DEBUG) -> None:
        for conn in conns:
            task = self._tasks.get(conn)
            if task is not None:
                self.dropped += 1
                log.log(level, "display: connection %d closed: %s", conn, why)
                task.cancel(why)

    async def _connection(self, reader: asyncio.StreamReader,
                          writer: asyncio.StreamWriter) -> None:
        conn, self._next_id = self._next_id, self._next_id + 1
        task = asyncio.current_task()
        assert task is not None
        self._tasks[conn] = task
        clean = False  # answered in full: close after the last byte; else abort at once
        # drain() waits until the kernel took every byte written: nothing is queued here
        writer.transport.set_write_buffer_limits(high=0)
        try:
            self._drop(self.admission.pending(conn), "the oldest of too many unfinished requests")
            try:
                head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HEADER_TIMEOUT_S)
                request = parse_request(head)
            except (TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError,
                    ValueError) as exc:
                if isinstance(exc, (ValueError, asyncio.LimitOverrunError)):
                    writer.write(response_head(HTTPStatus.BAD_REQUEST,
                                               "text/plain; charset=utf-8", 0))
                    await asyncio.wait_for(writer.drain(), STALL_S)
                    clean = True
                return
            answer = route(request, self.files)
            if answer is not None:
                self.admission.done(conn)
                status, content_type, body = answer
                writer.write(response_head(status, content_type, len(body)) + body)
                await asyncio.wait_for(writer.drain(), STALL_S)
                clean = True
                return
            self._drop(self.admission.stream(conn), f"a stream, for the newer one {conn} (more "
                       f"than {self.admission.max_streams} open)", logging.INFO)
            await self._stream(conn, writer)
        except (TimeoutError, asyncio.CancelledError, ConnectionError, OSError):
            pass  # dropped, stalled, or the page went away (a reload, a closed kiosk)
        finally:
            self.admission.done(conn)
            del self._tasks[conn]
            if clean:
                writer.transport.close()
            else:
                writer.transport.abort()

    async def _stream(self, conn: int, writer: asyncio.StreamWriter) -> None:
        writer.write(response_head(HTTPStatus.OK, "text/event-stream", None)
                     + f"retry: {RETRY_MS}\n\n".encode())
        while not self.feed.closed:
            assert self._tick is not None
            tick = self._tick
            _, payload = self.feed.latest()
            writer.write(f"data: {json.dumps(payload)}\n\n".encode())
            stuck = bool(writer.transport.get_write_buffer_size())  # the kernel's buffers are full
            self.admission.stalled(conn, stuck)
            # ConnectionError: the page went away; TimeoutError: its client stopped reading
            await asyncio.wait_for(writer.drain(), STALL_S)
            if stuck:
                self.admission.stalled(conn, False)
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(tick.wait(), KEEPALIVE_S)
