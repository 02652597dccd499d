"""A listen-only subscription whose samples wait in a bounded queue for the main thread.

Zenoh's thread only stamps the arrival time and queues the bytes; what would overflow the queue
(too many samples, or too many bytes: a burst of 256 kB camera frames) is counted and dropped,
never blocking the network. Used by the tools that only listen (`nod topic`, `nod status`) and
by the recorder (`nod record`).
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import zenoh

QUEUE_MAX = 10_000  # samples waiting for the main thread; more are dropped and counted
POLL_S = 0.1  # `next` returns at least this often (signals, deadlines)


@dataclass(frozen=True, slots=True)
class Arrival:
    """One sample as zenoh handed it over."""

    t: float  # time.monotonic() at arrival
    key: str
    payload: bytes
    wall_ns: int = 0  # time.time_ns() at arrival (the recorder's log time)


class Tap:
    """Subscriptions to one or more key expressions, feeding one bounded queue."""

    def __init__(
        self,
        session: zenoh.Session,
        expr: str | Sequence[str],
        maxsize: int = QUEUE_MAX,
        max_bytes: int | None = None,
    ) -> None:
        self.items: queue.Queue[Arrival] = queue.Queue(maxsize)
        self.dropped = 0
        self.max_bytes = max_bytes
        self._queued_bytes = 0
        self._lock = threading.Lock()  # guards the byte count (zenoh threads vs the reader)
        # On zenoh's thread, no hand-off queue: stamping at arrival keeps rates honest.
        exprs = [expr] if isinstance(expr, str) else list(expr)
        self._subs: list[Any] = []
        for e in exprs:
            callback = zenoh.handlers.Callback(self._on_sample, indirect=False)
            self._subs.append(session.declare_subscriber(e, callback))

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        payload = sample.payload.to_bytes()
        size = len(payload)
        with self._lock:
            if self.max_bytes is not None and self._queued_bytes + size > self.max_bytes:
                self.dropped += 1
                return
            item = Arrival(time.monotonic(), str(sample.key_expr), payload, time.time_ns())
            try:
                self.items.put_nowait(item)
            except queue.Full:  # the reader fell behind: never block zenoh's thread
                self.dropped += 1
                return
            self._queued_bytes += size

    def next(self, until: float | None = None) -> Arrival | None:
        """The next sample, waiting at most POLL_S and never past `until` (monotonic)."""
        timeout = POLL_S if until is None else min(POLL_S, until - time.monotonic())
        try:
            item = self.items.get_nowait() if timeout <= 0 else self.items.get(timeout=timeout)
        except queue.Empty:
            return None
        with self._lock:
            self._queued_bytes -= len(item.payload)
        return item

    def close(self) -> None:
        """Stop receiving (what is queued stays readable)."""
        for sub in self._subs:
            sub.undeclare()
        self._subs.clear()
