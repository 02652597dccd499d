"""Where the monitor's recording goes: file, spawned viewer, web viewer, a running viewer.

`open_sinks` turns the flags into Rerun sinks on one `RecordingStream` (all at once, so `--save`
and `--spawn` combine). `ViewerWatch` covers two gaps of the Rerun SDK (0.41, measured): a gRPC
sink whose viewer never came up buffers everything logged for it without a bound
(rerun-io/rerun#11519), and a viewer closed after it connected is not reconnected (the SDK drops
that sink's data, memory stays flat). So the monitor probes each viewer's port and, after a grace
period, stops (nothing else records) or warns once a minute (a file or the web server still does).
"""

from __future__ import annotations

import argparse
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import quote, urlsplit

import rerun as rr

from services.monitor.bridge import blueprint

SPAWN_PORT = 9876  # the Rerun viewer's default gRPC port


@dataclass
class Sinks:
    """What `open_sinks` attached: lines for the console and the viewers to watch."""

    lines: list[str] = field(default_factory=list)
    viewer_urls: list[str] = field(default_factory=list)
    keeps_data: bool = False  # a file or a served gRPC buffer records even without a viewer


def open_sinks(rec: rr.RecordingStream, args: argparse.Namespace) -> Sinks:
    """Attach the sinks the flags ask for (spawning/serving viewers as needed)."""
    out = Sinks()
    sinks: list[rr.GrpcSink | rr.GrpcServerSink | rr.FileSink] = []
    spawn = args.spawn or not (args.serve_web or args.save or args.viewer_url)
    if args.save is not None:
        args.save.parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(args.save), write_footer=not args.no_footer))
        out.lines.append(f"recording to {args.save} (open it with `rerun {args.save}`)")
        out.keeps_data = True
    if args.viewer_url:
        sinks.append(rr.GrpcSink(args.viewer_url))
        out.viewer_urls.append(args.viewer_url)
        out.lines.append(f"streaming to the viewer at {args.viewer_url}")
    server: rr.GrpcServerSink | None = None
    if args.serve_web:
        server = rr.GrpcServerSink(
            port=args.grpc_port, server_memory_limit=args.memory_limit, newest_first=True
        )
        sinks.append(server)
        out.keeps_data = True
    if spawn:
        port = args.grpc_port + 1 if args.serve_web else SPAWN_PORT
        exe = Path(sys.executable).with_name("rerun")  # the venv's viewer, even if not on PATH
        rr.spawn(
            recording=rec,  # without it the SDK looks for a global recording and skips the spawn
            port=port,
            connect=False,
            memory_limit=args.memory_limit,
            executable_path=str(exe) if exe.is_file() else None,
        )
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        sinks.append(rr.GrpcSink(url))
        out.viewer_urls.append(url)
        out.lines.append(f"native viewer spawned (gRPC port {port})")
    rec.set_sinks(*sinks, default_blueprint=blueprint())
    if server is not None:
        rr.serve_web_viewer(web_port=args.web_port, open_browser=False, connect_to=server.uri)
        host = socket.gethostname()  # an address a lab PC's browser can reach
        out.lines.append(f"web viewer: {web_viewer_url(server.uri, args.web_port, host)}")
        out.lines.append(
            "web viewer on this machine: "
            f"{web_viewer_url(server.uri, args.web_port, '127.0.0.1')} (from another machine, "
            f"if {host!r} does not resolve there, put this host's IP address in its place)"
        )
    return out


def web_viewer_url(grpc_uri: str, web_port: int, host: str) -> str:
    """The URL that opens the served web viewer on the served gRPC stream, both on `host`.

    The Rerun SDK (0.41) returns no URL from `serve_web_viewer`; its viewer takes the stream's
    address in `?url=`. The server binds 0.0.0.0, which a browser cannot connect to, so the
    host is put in its place.
    """
    parts = urlsplit(grpc_uri)
    grpc = grpc_uri.replace(parts.netloc, f"{host}:{parts.port}", 1)
    return f"http://{host}:{web_port}/?url={quote(grpc, safe='')}"


class ViewerWatch:
    """Probes the TCP port of each viewer the recording streams to."""

    def __init__(self, urls: list[str], *, period_s: float = 5.0) -> None:
        self.targets: list[tuple[str, int]] = []
        for url in urls:
            parts = urlsplit(url)
            self.targets.append((parts.hostname or "127.0.0.1", parts.port or SPAWN_PORT))
        self.period_s = period_s
        self._gone_since: float | None = None
        self._next = 0.0

    def gone_for(self, now: float | None = None) -> float:
        """Seconds since some viewer stopped accepting connections (0 while all are up)."""
        now = time.monotonic() if now is None else now
        if self.targets and now >= self._next:
            self._next = now + self.period_s
            if all(_reachable(t) for t in self.targets):
                self._gone_since = None
            elif self._gone_since is None:
                self._gone_since = now
        return 0.0 if self._gone_since is None else now - self._gone_since


def _reachable(target: tuple[str, int]) -> bool:
    try:
        with socket.create_connection(target, timeout=0.5):
            return True
    except OSError:
        return False
