"""A SIGTERM always stops a service, wherever its main thread is when the signal lands.

The process below spends nearly all its time inside `threading.Event.wait`, holding the event's
internal lock: the place where a handler that calls `event.set()` deadlocks its own thread (the
cause of the orphans a SIGKILLed launcher left). Each of many processes must stop cleanly.
"""

from __future__ import annotations

import signal
import subprocess
import sys

from tests.processes import ROOT

CHILD = """
import sys, threading
from services.core.node import install_signal_handlers
stop = threading.Event()
install_signal_handlers(stop, grace_s=30.0)
print("ready", flush=True)
while not stop.wait(0):
    pass
sys.exit(0)
"""


def _stops_cleanly_on(sig: signal.Signals) -> None:
    procs = [subprocess.Popen([sys.executable, "-c", CHILD], cwd=ROOT, stdout=subprocess.PIPE,
                              text=True) for _ in range(12)]
    try:
        for proc in procs:
            assert proc.stdout is not None and proc.stdout.readline() == "ready\n"
        for proc in procs:
            proc.send_signal(sig)
        # A clean stop is the loop seeing the event: exit 0, long before the 30 s forced exit.
        codes = [proc.wait(25) for proc in procs]
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
    assert codes == [0] * len(procs)


def test_sigterm_during_an_event_wait_stops_every_process_cleanly():
    _stops_cleanly_on(signal.SIGTERM)


def test_sigint_during_an_event_wait_stops_every_process_cleanly():
    _stops_cleanly_on(signal.SIGINT)
