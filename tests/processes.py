"""The tests' one way to run `nod …`, to stop the processes they started and to pick a port."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def run_nod(*args: str, timeout: float | None = None, **kw: Any) -> subprocess.CompletedProcess:
    """`nod ARGS…` from the repository root, its output captured as text."""
    return subprocess.run(
        [sys.executable, "-m", "services.cli", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
        **kw,
    )


def stop_all(procs: Iterable[subprocess.Popen]) -> None:
    """SIGTERM every live process, then wait up to 10 s for each and SIGKILL what is left."""
    procs = list(procs)
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
    for proc in procs:
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()


def free_port() -> int:
    """A TCP port nobody listens on right now on 127.0.0.1 (the OS picks it)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


MARK_ENV = "NOD_TEST_MARK"


def processes_marked(mark: str) -> dict[int, str]:
    """pid → command line of every live process whose environment carries `NOD_TEST_MARK=mark`.

    A test's children inherit the mark however deep they are spawned (a launcher's services,
    their helpers), so this finds what a test left behind even when it was re-parented to init
    after its launcher was SIGKILLed. Zombies are skipped: they hold nothing.
    """
    needle = f"{MARK_ENV}={mark}".encode()
    found: dict[int, str] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if needle not in (entry / "environ").read_bytes().split(b"\0"):
                continue
            if (entry / "stat").read_text().rsplit(")", 1)[1].split()[0] == "Z":
                continue
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, IndexError):
            continue  # gone while we looked, or not ours to read
        found[int(entry.name)] = cmdline.strip()
    return found
