"""SIGINT and SIGTERM handed to a helper thread: nothing is done inside a signal handler.

Python runs a signal handler on the main thread between two bytecodes, wherever that thread is,
including inside `threading.Event.wait` at the moment it holds the event's internal (plain,
non-reentrant) lock. A handler that calls `event.set()` there waits for a lock its own thread
holds: the process hangs for good and ignores every later SIGTERM. That was the orphan a
SIGKILLed `nod up` left behind now and then: a service whose parent-death SIGTERM landed while
its main loop waited on its stop event, with the forced exit never armed because arming it came
after the `set()`.

So the Python-level handler does nothing at all. Its C-level part still writes the signal's
number to a wake-up pipe (`signal.set_wakeup_fd`); a daemon thread reads that pipe and runs the
registered callbacks, on an ordinary thread where taking a lock is safe.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from collections.abc import Callable
from types import FrameType

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
log = logging.getLogger(__name__)

_lock = threading.Lock()
_callbacks: list[Callable[[int], object]] = []
_pipe_write_end: int | None = None


def _noted(_signum: int, _frame: FrameType | None) -> None:
    """The Python-level handler: nothing, on purpose (see the module's docstring)."""


def on_stop_signal(callback: Callable[[int], object]) -> bool:
    """Run `callback(signum)` on a helper thread at every SIGINT/SIGTERM; False off the main thread.

    Callbacks run in the order registered; one that raises is logged and the others still run.
    Only the main thread may install signal handlers, so elsewhere nothing is installed.
    """
    if threading.current_thread() is not threading.main_thread():
        return False
    global _pipe_write_end
    with _lock:
        _callbacks.append(callback)
        for sig in STOP_SIGNALS:  # again each time: a bench tool may have swapped one meanwhile
            signal.signal(sig, _noted)
        if _pipe_write_end is None:
            r, w = os.pipe()
            os.set_blocking(w, False)  # the C handler must never block on a full pipe
            signal.set_wakeup_fd(w, warn_on_full_buffer=False)
            _pipe_write_end = w
            threading.Thread(target=_watch, args=(r,), name="stop-signals", daemon=True).start()
    return True


def _watch(read_end: int) -> None:
    while True:
        for signum in os.read(read_end, 64):
            if signum not in STOP_SIGNALS:
                continue
            with _lock:
                callbacks = list(_callbacks)
            for callback in callbacks:
                try:
                    callback(signum)
                except Exception:  # one broken callback must not keep the others from stopping
                    log.exception("stop-signal callback failed")
