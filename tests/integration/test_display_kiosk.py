"""The kiosk always gets its screen: 500 idle connections to the real `nod display` process (half
silent, half stuck in their request's headers) neither lock the participant's page out nor grow
the process — its threads and its resident memory read from /proc/<pid>/status."""

from __future__ import annotations

import json
import select
import socket
import time
import urllib.request
from pathlib import Path

import pytest

from services.core.keys import Keys

from .conftest import wait_for
from .test_display_page import Conductor, _served_url

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")
IDLE = 500
MORE_THREADS = 2  # the page's server is one thread whatever it serves; slack for the runtime's
MORE_RSS_KB = 32 * 1024  # measured: about 3 MB for 500 connections


def _status(pid: int) -> tuple[int, int]:
    """(threads, resident kB) of a process, from /proc/<pid>/status."""
    lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    fields = dict(line.split(":", 1) for line in lines)
    return int(fields["Threads"]), int(fields["VmRSS"].split()[0])


def _next_screen(stream) -> dict:
    """The next screen an open event stream sends."""
    while True:
        line = stream.readline().decode()
        assert line, "the stream ended"
        if line.startswith("data: "):
            return json.loads(line[6:])


def _closed(sock: socket.socket) -> bool:
    """The server closed `sock` (EOF or a reset); never blocks."""
    if not select.select([sock], [], [], 0)[0]:
        return False
    try:
        return sock.recv(1024) == b""
    except OSError:
        return True


def test_500_idle_connections_neither_lock_the_kiosk_out_nor_grow_the_process(
    router, client, spawn
):
    display = spawn("display", "--http", "127.0.0.1:0")
    url = wait_for(lambda: _served_url(display) or (display.poll() is not None and "exited"),
                   30, "the display's URL in its log")
    assert url != "exited", display.log_path.read_text()[-2000:]
    host, port = "127.0.0.1", int(url.rsplit(":", 1)[1].strip("/"))
    wait_for(lambda: any(r.ok is not None for r in client.liveliness().get(
        KEYS.alive("display"), timeout=0.3)), 30, "the display up")
    conductor = Conductor(client)
    conductor.alive(True)
    wait_for(lambda: "the conductor is up" in display.log_path.read_text(), 30,
             "the display seeing the conductor")
    conductor.event("setup", 1)
    conductor.event("go", 1, text="go")
    kiosk = urllib.request.urlopen(url + "events", timeout=10)  # the kiosk, open all along
    wait_for(lambda: _next_screen(kiosk)["kind"] == "go", 30, "the kiosk showing go")
    threads_before, rss_before = _status(display.pid)

    idle: list[socket.socket] = []
    try:
        for i in range(IDLE):
            sock = socket.create_connection((host, port), timeout=10)
            if i % 2:  # a request whose headers never end
                sock.sendall(b"GET /events HTTP/1.1\r\nHost: " + host.encode() + b"\r\n")
            idle.append(sock)
        threads_idle, rss_idle = _status(display.pid)

        # The kiosk's open stream carries on, and a reload gets its page and screen at once.
        assert _next_screen(kiosk)["kind"] == "go"
        start = time.monotonic()
        with urllib.request.urlopen(url, timeout=10) as page:
            assert b'<div id="big">' in page.read()
        reloaded = urllib.request.urlopen(url + "events", timeout=10)
        assert _next_screen(reloaded)["kind"] == "go"
        took_s = time.monotonic() - start
        conductor.event("end", 1)  # and each new screen reaches both
        wait_for(lambda: _next_screen(reloaded)["kind"] == "wait", 10, "the reload's next screen")
        wait_for(lambda: _next_screen(kiosk)["kind"] == "wait", 10, "the kiosk's next screen")
        threads_after, rss_after = _status(display.pid)
        print(f"{IDLE} idle connections: threads {threads_before} → {threads_idle} → "
              f"{threads_after}, VmRSS {rss_before} → {rss_idle} → {rss_after} kB; the page and "
              f"its screen after a reload in {took_s * 1e3:.0f} ms")
        assert took_s < 3.0
        assert max(threads_idle, threads_after) <= threads_before + MORE_THREADS
        assert max(rss_idle, rss_after) <= rss_before + MORE_RSS_KB

        # Every idle connection is closed by the server: the oldest for newer ones, the rest
        # when their headers did not come in time.
        open_idle = list(idle)

        def all_closed() -> bool:
            open_idle[:] = [s for s in open_idle if not _closed(s)]
            return not open_idle

        wait_for(all_closed, 30, "the server closing every idle connection", every_s=0.1)
        assert _next_screen(kiosk)["kind"] == "wait"  # the kiosk's stream was never one of them
        reloaded.close()
    finally:
        kiosk.close()
        for sock in idle:
            sock.close()
