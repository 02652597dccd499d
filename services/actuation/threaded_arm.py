"""A bus-driven arm on its own thread: the service's calls never wait for the serial bus.

The Feetech driver talks to its servos inside `state(t)` and `hold()` (goal writes, health
reads, reconnects), and a silent bus costs timeouts. `ThreadedArm` wraps such a driver: the
service's calls queue commands and return at once, `state(t)` returns the newest report the
I/O thread made, and the thread applies the commands in order and steps the driver at the time
the service last asked for. So the actuation tick — its safety gate and its state key — keeps
its pace whatever the bus does; a hold is applied before anything queued behind it. It speaks
the words of the driver it wraps (`arm_words.py`): the paper's colours or N boxes by index.
"""

from __future__ import annotations

import functools
import logging
import threading
from collections import deque
from collections.abc import Callable
from typing import Generic, Protocol, TypeVar

from services.actuation.arm_words import ArmWords, C, R, T
from services.model.device import Device
from services.model.geometry import Point

log = logging.getLogger(__name__)
STOP_WAIT_S = 1.0  # how long disconnect() waits for the thread's last hold and its exit
X = TypeVar("X")


class BusArm(Protocol[C, T, R]):
    """An arm driver whose calls may block on I/O (`FeetechArm`), as the thread drives it."""

    words: ArmWords[C, T, R]

    @property
    def is_connected(self) -> bool:
        """Whether the driver is connected."""

    def connect(self) -> None:
        """Open the bus (blocks)."""

    def disconnect(self) -> None:
        """Close the bus."""

    def send(self, cmd: C) -> C:
        """Apply a command."""

    def home(self) -> C:
        """Back to the rest pose."""

    def hold(self) -> C:
        """Safe stop: hold where it is."""

    def state(self, t: float) -> R:
        """Step to time t (s) and report."""

    def ee_estimate(self) -> Point:
        """Where the end effector is estimated to be (before the first report)."""


class ThreadedArm(Device, Generic[C, T, R]):
    """Wraps a `BusArm`; every call here returns at once."""

    def __init__(self, inner: BusArm[C, T, R]) -> None:
        """Wrap `inner`; nothing runs until `connect()`."""
        self.inner = inner
        self.words = inner.words
        self._lock = threading.Lock()  # guards the fields below, never held during I/O
        self._queue: deque[Callable[[], object]] = deque()
        self._t: float | None = None  # the time of the newest state(t) asked for
        self._report: R | None = None
        self._wake = threading.Event()
        self._quit = threading.Event()
        self._worker: threading.Thread | None = None

    @property
    def is_connected(self) -> bool:
        """Whether the inner driver is connected."""
        return self.inner.is_connected

    @property
    def fault(self) -> str | None:
        """The fault of the newest report (or None)."""
        report = self._report
        return report.fault if report is not None else None

    def connect(self) -> None:
        """Connect the inner driver, then start the I/O thread.

        Connecting blocks: at start-up an arm that does not answer must be an error.
        """
        self.inner.connect()
        self._quit.clear()
        self._worker = threading.Thread(target=self._run, name="arm I/O", daemon=True)
        self._worker.start()

    def disconnect(self) -> None:
        """Let the thread apply what is queued (a hold first of all), stop it, disconnect."""
        if self._worker is not None:
            self._quit.set()
            self._wake.set()
            self._worker.join(STOP_WAIT_S)
            self._worker = None
        self.inner.disconnect()

    def send(self, cmd: C) -> C:
        """Queue a command; return it (or the stop a faulted arm turns it into)."""
        with self._lock:
            self._queue.append(lambda: self.inner.send(cmd))
        self._wake.set()
        fault = self.fault
        if fault is not None and cmd.action in ("move", "press"):
            return self.words.stop(f"refused {cmd.action}: fault {fault}")
        return cmd

    def hold(self) -> C:
        """Safe stop: drop every queued command and hold, before anything else."""
        with self._lock:
            self._queue.clear()
            self._queue.append(self.inner.hold)
        self._wake.set()
        return self.words.stop("hold")

    def make_safe(self) -> C:
        """Hold the arm (before disconnecting)."""
        return self.hold()

    def home(self) -> C:
        """Queue the way home (and the end of the trial's press)."""
        with self._lock:
            self._queue.append(self.inner.home)
        self._wake.set()
        return self.words.idle("going home")

    def state(self, t: float) -> R:
        """Ask the thread to step the arm to time t; return the newest report at once."""
        with self._lock:
            self._t = t if self._t is None else max(self._t, t)
            report = self._report
        self._wake.set()
        if report is None:  # before the thread's first report: where the driver estimates it is
            return self.words.report(t, self.inner.ee_estimate(), False, None, None, "starting")
        return report

    def settle(self, timeout_s: float) -> bool:
        """Wait until the thread has applied everything asked so far (tests, shutdown)."""
        done = threading.Event()
        with self._lock:
            self._queue.append(done.set)
        self._wake.set()
        return done.wait(timeout_s)

    def _run(self) -> None:
        while True:
            self._wake.wait()
            self._wake.clear()
            with self._lock:
                jobs = list(self._queue)
                self._queue.clear()
                t = self._t
            for job in jobs:
                self._call(job)
            if t is not None:
                report = self._call(functools.partial(self.inner.state, t))
                if report is not None:
                    with self._lock:
                        self._report = report
            if self._quit.is_set():
                return

    def _call(self, job: Callable[[], X]) -> X | None:
        try:
            return job()
        except Exception:  # the I/O thread must outlive any driver surprise
            log.exception("arm I/O failed")
            return None
