"""What the rig tools share: their session, a rig's keys, strict decoding, arrival rates.

`nod topic` and `nod status` open the session their flags describe, resolve keys against the
contract, decode what arrives with the contract's strict decoders and measure arrival rates.
"""

from __future__ import annotations

import argparse
import math
import re
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import zenoh

from services.core import messages as m
from services.core.contract import TOPICS
from services.core.keys import check_rig, topic_of
from services.core.node import clip, install_signal_handlers
from services.core.session import Fabric, open_session
from services.core.tap import Arrival, Tap

# A host clock this far (ms) from ours is flagged by `nod status` and `nod lab status`: the
# safety bounds compare timestamps across hosts (docs/safety.md §1).
CLOCK_WARN_MS = 20.0


class ToolError(Exception):
    """Bad input or an unreachable rig: one line on stderr, exit 2."""


# --- keys ---------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Target:
    """What a KEY argument names: the key expression to subscribe to and the topics it covers."""

    expr: str  # e.g. nod/rig1/vision/hand, nod/rig1/safety/*
    topics: tuple[str, ...]  # the contract topics it matches

    @property
    def is_pattern(self) -> bool:
        """True if the expression has wildcards (it may match several keys)."""
        return "*" in self.expr or "$" in self.expr


def resolve(key: str, rig: str) -> Target:
    """The key expression of a KEY argument (full, or relative to `rig`); ToolError if unknown."""
    text = key.strip().strip("/")
    if text == "nod" or text.startswith("nod/"):
        parts = text.split("/", 2)
        if len(parts) < 3 or not parts[2]:
            raise ToolError(f"key {key!r} names no topic: give nod/<rig>/<topic> or a topic, "
                            "e.g. vision/hand")
        _, rig, name = parts
        if rig != "*":
            try:
                check_rig(rig)
            except ValueError as exc:
                raise ToolError(str(exc)) from None
    else:
        name = text
    if not name:
        raise ToolError("empty key: give a topic, e.g. vision/hand")
    if "*" in name or "$" in name:
        try:
            pattern = zenoh.KeyExpr(name)
        except zenoh.ZError as exc:
            raise ToolError(f"{key!r} is not a key expression: {clean(str(exc))}") from None
        # A key only ever queried (the e-stop latch) carries no samples to listen to.
        topics = tuple(
            t for t, spec in TOPICS.items()
            if not spec.queried_only and pattern.intersects(zenoh.KeyExpr(t))
        )
    else:
        topics = (name,) if name in TOPICS else ()
    if not topics:
        raise ToolError(
            f"unknown key {key!r}: the contract's keys (nod/<rig>/...) are {', '.join(TOPICS)}"
        )
    return Target(f"nod/{rig}/{name}", topics)


def decode(key: str, payload: bytes) -> m.Message:
    """The message on a full key, strictly validated; MessageError says why not."""
    topic = topic_of(key)
    if topic is None:
        raise m.MessageError("not a key of the contract: no decoder")
    return m.decode(TOPICS[topic].message, payload)


class Window:
    """One listening window: the samples of some keys, decoded, and who is alive meanwhile.

    The tools that only listen (`nod status`, `nod lab status`, `nod topic list`) open one;
    the liveliness tokens under `alive` go to `on_alive` with their history (who was alive
    before the window opened). Use it in a `with` block: leaving it undeclares both subscriptions.
    """

    def __init__(
        self,
        session: zenoh.Session,
        expr: str | Sequence[str],
        alive: str,
        on_alive: Callable[[zenoh.Sample], None],
    ) -> None:
        self.tap = Tap(session, expr)
        try:
            self._watch = session.liveliness().declare_subscriber(alive, on_alive, history=True)
        except BaseException:
            self.tap.close()
            raise

    def __enter__(self) -> Window:
        return self

    def __exit__(self, *exc: object) -> None:
        self.tap.close()
        self._watch.undeclare()

    def heard(
        self, deadline: float, stop: threading.Event
    ) -> Iterator[tuple[Arrival, m.Message | None]]:
        """Each sample until `deadline` (monotonic) or `stop`, with its message (None: invalid)."""
        while not stop.is_set() and time.monotonic() < deadline:
            item = self.tap.next(deadline)
            if item is None:
                continue
            msg: m.Message | None
            try:
                msg = decode(item.key, item.payload)
            except m.MessageError:
                msg = None
            yield item, msg


def clean(text: str) -> str:
    """One short line of a zenoh error: the message itself, without the Rust source locations."""
    inner = re.search(r'msg: "(.*?)"', text)  # a config error wraps its text in Json5Err(...)
    if inner:
        text = inner.group(1)
    text = re.sub(r"\s*\bat \S+\.rs:\d+\.?", "", text)
    return clip(text, 300)


# --- rates --------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Stats:
    """The arrival rate of some messages and the spread of the intervals between them."""

    count: int  # messages
    rate_hz: float
    min_s: float
    max_s: float
    std_s: float

    def describe(self) -> str:
        """`50.0 Hz  min 19.6 ms  max 20.4 ms  std 0.21 ms`."""
        return (
            f"{self.rate_hz:.1f} Hz  min {_ms(self.min_s)}  max {_ms(self.max_s)}  "
            f"std {_ms(self.std_s)}"
        )

    def as_json(self) -> dict[str, Any]:
        """The statistics as a JSON object."""
        return {
            "count": self.count,
            "rate_hz": round(self.rate_hz, 3),
            "min_ms": round(self.min_s * 1e3, 3),
            "max_ms": round(self.max_s * 1e3, 3),
            "std_ms": round(self.std_s * 1e3, 3),
        }


def _ms(seconds: float) -> str:
    ms = seconds * 1e3
    return f"{ms:.1f} ms" if ms >= 10 else f"{ms:.2f} ms"


def interval_stats(times: Iterable[float]) -> Stats | None:
    """Statistics of arrival times (ascending); None with fewer than two."""
    times = list(times)
    if len(times) < 2 or times[-1] <= times[0]:
        return None
    gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
    mean = (times[-1] - times[0]) / len(gaps)
    std = math.sqrt(sum((g - mean) ** 2 for g in gaps) / len(gaps))
    return Stats(len(times), 1.0 / mean, min(gaps), max(gaps), std)


class Rate:
    """Arrivals of one key: the last `window` arrival times, and running totals of every one."""

    def __init__(self, window: int = 100) -> None:
        self.recent: deque[float] = deque(maxlen=max(2, window))
        self.count = 0
        self.first: float | None = None
        self.last: float | None = None
        self._gaps = 0
        self._mean = 0.0  # Welford's running mean and sum of squares of the intervals
        self._m2 = 0.0
        self._min = math.inf
        self._max = 0.0

    def add(self, t: float) -> None:
        """Record an arrival at monotonic time `t`."""
        if self.last is None:
            self.first = t
        else:
            gap = max(0.0, t - self.last)
            self._gaps += 1
            delta = gap - self._mean
            self._mean += delta / self._gaps
            self._m2 += delta * (gap - self._mean)
            self._min = min(self._min, gap)
            self._max = max(self._max, gap)
        self.last = t
        self.count += 1
        self.recent.append(t)

    def window(self) -> Stats | None:
        """Statistics of the last `window` arrivals."""
        return interval_stats(self.recent)

    def total(self) -> Stats | None:
        """Statistics of every arrival so far."""
        if self._gaps == 0 or self._mean <= 0:
            return None
        std = math.sqrt(self._m2 / self._gaps)
        return Stats(self.count, 1.0 / self._mean, self._min, self._max, std)


def connect(args: argparse.Namespace) -> zenoh.Session:
    """The session the flags describe; ToolError (one line) if it cannot open."""
    try:
        fabric = Fabric.from_args(args)
        return open_session(fabric.zenoh_config())
    except zenoh.ZError as exc:  # the configuration itself (open_session turns the rest into
        # ConnectionError): a malformed endpoint, a config file zenoh refuses
        raise ToolError(f"bad zenoh session flags: {clean(str(exc))}") from None
    except (ConnectionError, OSError, ValueError) as exc:
        raise ToolError(clean(str(exc))) from None


def listen(args: argparse.Namespace) -> tuple[zenoh.Session, threading.Event]:
    """`connect`, and the event SIGINT or SIGTERM sets.

    A tool that listens stops cleanly on either: its subscriptions undeclared, the session
    closed, what it heard reported.
    """
    session = connect(args)
    stop = threading.Event()
    install_signal_handlers(stop)
    return session, stop


def print_line(line: str) -> None:
    """One line of a tool's output, flushed at once (it is read live, often through a pipe)."""
    print(line, flush=True)
