"""A bounded hand-off from Zenoh's delivery threads to the monitor's single logger thread.

Three lanes, each with a fixed capacity, so memory stays bounded however fast keys arrive:

- `events` (every opinion, state, trial event, result, estop): sized generously (default 200 000
  items, minutes of every key at 120 Hz) and never drops while there is room; if it ever fills,
  the newest sample is dropped and counted, and the monitor reports it.
- `hand` (hand poses, 120 Hz) and `frame` (JPEG frames): lossy; when full the oldest sample goes,
  so a slow viewer shows the newest hand, not a backlog.

`put` only appends under a lock: a Zenoh callback never waits for Rerun.
"""

from __future__ import annotations

import threading
from collections import Counter, deque
from dataclasses import dataclass
from typing import Literal

Lane = Literal["events", "hand", "frame"]
LOSSY: frozenset[Lane] = frozenset({"hand", "frame"})


@dataclass(frozen=True, slots=True)
class Item:
    """One raw sample: its topic (e.g. "vision/hand") and its payload bytes."""

    topic: str
    payload: bytes


class Inbox:
    """Bounded multi-producer, single-consumer queue with per-lane drop accounting."""

    def __init__(self, *, events: int = 200_000, hand: int = 240, frame: int = 4) -> None:
        caps = {"events": events, "hand": hand, "frame": frame}
        for lane, cap in caps.items():
            if cap < 1:
                raise ValueError(f"inbox lane {lane!r} needs a capacity >= 1, got {cap}")
        self.capacity: dict[Lane, int] = caps  # type: ignore[assignment]
        self._lanes: dict[Lane, deque[Item]] = {lane: deque() for lane in self.capacity}
        self._cond = threading.Condition()
        self._closed = False
        self.received: Counter[str] = Counter()  # per lane
        self.dropped: Counter[str] = Counter()  # per lane
        self.high_water: Counter[str] = Counter()  # deepest each lane has been

    def put(self, lane: Lane, item: Item) -> bool:
        """Queue one sample; False if it (or, on a lossy lane, an older one) had to be dropped."""
        with self._cond:
            if self._closed:
                return False
            q = self._lanes[lane]
            self.received[lane] += 1
            kept = True
            if len(q) >= self.capacity[lane]:
                self.dropped[lane] += 1
                kept = False
                if lane not in LOSSY:
                    return False  # never evict a queued opinion or event: drop the newest
                q.popleft()
            q.append(item)
            if len(q) > self.high_water[lane]:
                self.high_water[lane] = len(q)
            self._cond.notify()
            return kept

    def get_batch(self, timeout: float, max_items: int = 2000) -> list[Item]:
        """Up to `max_items` queued samples, events first; waits up to `timeout` for one."""
        with self._cond:
            if not self._closed and not any(self._lanes.values()):
                self._cond.wait(timeout)
            out: list[Item] = []
            for q in self._lanes.values():
                while q and len(out) < max_items:
                    out.append(q.popleft())
            return out

    def depth(self) -> int:
        """How many samples are waiting, all lanes together."""
        with self._cond:
            return sum(len(q) for q in self._lanes.values())

    def close(self) -> None:
        """Refuse new samples and wake the consumer so it drains what is left and stops."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        """Whether `close()` was called."""
        return self._closed


def lane_of(topic: str) -> Lane:
    """The lane a topic's samples travel in."""
    if topic == "vision/hand":
        return "hand"
    if topic == "vision/frame":
        return "frame"
    return "events"
