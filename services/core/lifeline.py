"""A child process that ends with its launcher, even when the launcher is killed with SIGKILL.

A launcher that is SIGKILLed runs no cleanup, and its children (each in its own session, so
that the launcher's Ctrl-C does not hit them unordered) would run on as orphans: a driver
holding a serial port, a sim publishing into a rig. The launcher puts its pid in
`NOD_PARENT_PID`; `die_with_parent()`, called first thing by the `nod` entry point, asks the
Linux kernel for a SIGTERM when the parent dies (prctl PR_SET_PDEATHSIG) — the service's normal
SIGTERM path then stops it cleanly, device to its safe state. If the parent is already gone
(it died between fork and this call) the process exits at once.

`nod_command(...)` is how every launcher writes a child's command line: this interpreter, with
`-P` so that the working directory is not on the child's `sys.path` (a stray `serial.py` or
`zenoh.py` where the launcher was started must not shadow the real package in a service).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import sys

PR_SET_PDEATHSIG = 1


def nod_command(*args: str) -> list[str]:
    """`nod ARGS…` as a child process: `python -P -m services.cli ARGS…`.

    `-P` (Python >= 3.11) keeps the working directory off `sys.path` and changes nothing else:
    the environment (NOD_*, PYTHONPATH, PYTHONUNBUFFERED…) and site-packages work as before. The
    `nod` console script is safe already (its `sys.path[0]` is the venv's bin folder).
    """
    return [sys.executable, "-P", "-m", "services.cli", *args]


def die_with_parent(sig: int = signal.SIGTERM) -> bool:
    """Arrange `sig` on the parent's death when NOD_PARENT_PID is set; True if arranged."""
    expected = os.environ.get("NOD_PARENT_PID")
    if not expected or not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
            return False
    except (OSError, AttributeError):
        return False
    if str(os.getppid()) != expected:  # the launcher died before we asked: we are an orphan
        os._exit(128 + int(sig))
    return True
