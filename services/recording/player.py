"""Playing a recording onto a live rig (`nod replay`'s player).

Plain, restamped onto the rig clock, or following the live conductor's trial events: the
module documentation of `services.recording.replay` says what each does.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import statistics
import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field

import msgspec
import zenoh

from services.core import messages as m
from services.core.clock import Clock
from services.core.contract import TOPICS
from services.core.keys import Keys, topic_of
from services.core.node import declare_publisher
from services.recording.mcap_io import (
    Entry,
    McapIn,
)
from services.recording.selection import (
    ANCHOR_PHASES,
    END_PHASES,
    PROG,
    Anchor,
    decode_entry,
)

log = logging.getLogger("nod.replay")
POLL_S = 0.005  # a waiting player looks at the live events this often


@dataclass(frozen=True, slots=True)
class LiveEvent:
    """A trial event of the live conductor."""

    phase: str
    trial: int
    t_ns: int


class LiveEvents:
    """The live conductor's setup/go/session_end events, queued for the player."""

    def __init__(self, session: zenoh.Session, keys: Keys) -> None:
        self.items: queue.Queue[LiveEvent] = queue.Queue(1000)
        self._sub = session.declare_subscriber(keys.topic("experiment/trial"), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        try:
            ev = m.decode(m.TrialEvent, sample.payload.to_bytes())
        except m.MessageError:
            return
        if ev.phase in ANCHOR_PHASES + END_PHASES:
            with contextlib.suppress(queue.Full):  # a stuck player: the newest are lost
                self.items.put_nowait(LiveEvent(ev.phase, ev.trial, ev.t_ns))

    def get(self) -> LiveEvent | None:
        """The next live event, or None."""
        try:
            return self.items.get_nowait()
        except queue.Empty:
            return None

    def close(self) -> None:
        """Stop listening."""
        self._sub.undeclare()


@dataclass
class PlayStats:
    """How a replay went."""

    sent: int = 0
    skipped: int = 0  # passed over to catch up with the live conductor
    repeated: int = 0  # hand poses repeated while waiting for it
    holds: int = 0
    hold_s: float = 0.0
    jumps: int = 0
    undecodable: int = 0
    lateness_s: list[float] = field(default_factory=list)
    elapsed_s: float = 0.0

    def line(self) -> str:
        """The one-line summary."""
        text = f"{PROG}: {self.sent} messages sent in {self.elapsed_s:.1f} s"
        if self.lateness_s:
            late = sorted(self.lateness_s)
            p = late[min(len(late) - 1, int(0.99 * len(late)))]
            text += (
                f"; sent late by median {statistics.median(late) * 1e3:.2f} ms, "
                f"p99 {p * 1e3:.2f} ms, max {late[-1] * 1e3:.1f} ms"
            )
        if self.holds or self.jumps:
            text += (
                f"; followed the live conductor: waited {self.holds}x ({self.hold_s:.2f} s, "
                f"{self.repeated} poses repeated), skipped ahead {self.jumps}x "
                f"({self.skipped} messages)"
            )
        if self.undecodable:
            text += f"; {self.undecodable} undecodable payloads not restamped (skipped)"
        return text


class Player:
    """Sends a recording's messages onto a rig, plain, restamped, or following the conductor."""

    def __init__(
        self,
        session: zenoh.Session,
        rig: str,
        topics: set[str],
        stop: threading.Event,
        *,
        speed: float = 1.0,
        clock: Clock | None = None,
        follow: LiveEvents | None = None,
        follow_timeout_s: float = 60.0,
        hand_period_ns: int = 33_333_333,
    ) -> None:
        self.session, self.keys, self.topics, self.stop = session, Keys(rig), topics, stop
        self.speed = speed
        self.clock = clock  # None: plain bytes, log-time pacing
        self.follow = follow
        self.follow_timeout_s = follow_timeout_s
        self.hand_period_ns = hand_period_ns
        self.stats = PlayStats()
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._seq: dict[str, int] = defaultdict(int)
        self._last_t: dict[str, int] = {}
        self._last_msg: dict[str, m.Message] = {}  # per topic, for repeats while holding
        self._delta: int | None = None  # rig stamp = recorded stamp + delta
        self._wall0: float | None = None  # plain pacing: wall start and first log time
        self._log0 = 0
        self._live_pending: LiveEvent | None = None
        self.live_ended = False

    # -- sending --------------------------------------------------------------------------------

    def _pub(self, topic: str) -> zenoh.Publisher:
        pub = self._pubs.get(topic)
        if pub is None:
            pub = self._pubs[topic] = declare_publisher(
                self.session, self.keys.topic(topic), TOPICS[topic].qos
            )
        return pub

    def _send_restamped(self, topic: str, msg: m.Message, t_ns: int) -> None:
        t = max(t_ns, self._last_t.get(topic, -1) + 1)  # stamps never go back on a key
        self._last_t[topic] = t
        seq = self._seq[topic]
        self._seq[topic] += 1
        new = msgspec.structs.replace(msg, seq=seq, t_ns=t)
        self._pub(topic).put(m.encode(new))
        self._last_msg[topic] = msg

    def close(self) -> None:
        """Undeclare the publishers."""
        for pub in self._pubs.values():
            pub.undeclare()
        self._pubs.clear()

    # -- the loop -------------------------------------------------------------------------------

    def play(self, src: McapIn, anchors: list[Anchor]) -> None:
        """One pass over the recording."""
        t_start = time.monotonic()
        next_anchor = 0
        skip_to: int | None = None  # skipping ahead to this anchor (index into `anchors`)
        skipped_last: dict[str, tuple[m.Message, int]] = {}
        self._wall0 = None
        if self.clock is not None and self.follow is None:
            self._delta = None  # a new pass (--loop): anchored again at its first message
        for e in src:
            if self.stop.is_set():
                break
            # Recorded trial events at or before this message: meet the live conductor there.
            while (self.follow is not None and next_anchor < len(anchors)
                   and anchors[next_anchor].index <= e.index):
                a = anchors[next_anchor]
                if skip_to is not None and next_anchor < skip_to:
                    next_anchor += 1  # an anchor passed over while catching up
                    continue
                if skip_to is not None:  # reached the anchor the live conductor is at
                    skip_to = None
                    live = self._live_pending
                    self._live_pending = None
                    self._flush_skipped(skipped_last, live, a)
                    skipped_last = {}
                else:
                    live, jump = self._hold(a, anchors, next_anchor)
                    if jump is not None:  # the live conductor is further than this anchor
                        skip_to, self._live_pending = jump
                        next_anchor += 1
                        continue
                if live is not None:
                    self._delta = live.t_ns - a.t_ns
                next_anchor += 1
            topic = topic_of(e.key)
            if topic not in self.topics or not e.valid:
                continue
            if skip_to is not None:
                self._skip(topic, e, skipped_last)
                continue
            if self.clock is None:
                self._play_plain(topic, e)
                continue
            msg = decode_entry(topic, e)
            if msg is None:
                self.stats.undecodable += 1
                continue
            if self._delta is None:
                self._delta = self.clock.now_ns() - msg.t_ns
            due = msg.t_ns + self._delta
            jump = self._wait_rig(due, anchors, next_anchor)
            if jump is not None:  # the live conductor moved on: catch up from here
                skip_to, self._live_pending = jump
                self._skip(topic, e, skipped_last)
                continue
            lateness = (self.clock.now_ns() - due) / 1e9 / self.clock.speed
            self._send_restamped(topic, msg, due)
            self._note(lateness)
        if self.follow is not None and not self.stop.is_set():
            self._hold_until_the_end()
        self.stats.elapsed_s += time.monotonic() - t_start

    def _note(self, lateness_s: float) -> None:
        self.stats.sent += 1
        if len(self.stats.lateness_s) < 500_000:
            self.stats.lateness_s.append(max(0.0, lateness_s))

    def _play_plain(self, topic: str, e: Entry) -> None:
        log_time = e.message.log_time
        if self._wall0 is None:
            self._wall0, self._log0 = time.monotonic(), log_time
        due = self._wall0 + (log_time - self._log0) / 1e9 / self.speed
        while not self.stop.is_set():
            wait = due - time.monotonic()
            if wait <= 0:
                break
            self.stop.wait(min(wait, 0.05))
        self._pub(topic).put(e.payload)
        self._note(time.monotonic() - due)

    def _skip(self, topic: str, e: Entry, skipped_last: dict[str, tuple[m.Message, int]]) -> None:
        """A message passed over while catching up; the last one of a state key is kept."""
        self.stats.skipped += 1
        if TOPICS[topic].qos.congestion == "block":  # state (the layout): its latest value counts
            msg = decode_entry(topic, e)
            if msg is not None:
                skipped_last[topic] = (msg, msg.t_ns)

    def _flush_skipped(self, skipped_last: dict[str, tuple[m.Message, int]],
                       live: LiveEvent | None, a: Anchor) -> None:
        delta = (live.t_ns - a.t_ns) if live is not None else self._delta or 0
        for topic, (msg, t_ns) in skipped_last.items():
            self._send_restamped(topic, msg, max(t_ns + delta, 0))
            self.stats.sent += 1

    def _match(self, ev: LiveEvent, anchors: list[Anchor], start: int) -> int | None:
        for j in range(start, len(anchors)):
            if (anchors[j].phase, anchors[j].trial) == (ev.phase, ev.trial):
                return j
        return None

    def _take_live(self, anchors: list[Anchor], start: int) -> tuple[int, LiveEvent] | None:
        """The next live event that matches an anchor from `start` on (others are logged)."""
        assert self.follow is not None
        while (ev := self.follow.get()) is not None:
            if ev.phase in END_PHASES:
                self.live_ended = True
                continue
            j = self._match(ev, anchors, start)
            if j is not None:
                return j, ev
            log.warning("live %s of trial %d matches no recorded event ahead; ignored",
                        ev.phase, ev.trial)
        return None

    def _wait_rig(self, due_ns: int, anchors: list[Anchor],
                  next_anchor: int) -> tuple[int, LiveEvent] | None:
        """Sleep until the rig clock reads `due_ns`; a live event ahead of us ends the wait."""
        assert self.clock is not None
        while not self.stop.is_set():
            if self.follow is not None:
                taken = self._take_live(anchors, next_anchor)
                if taken is not None:
                    j, ev = taken
                    self.stats.jumps += 1
                    return j, ev
            wait = (due_ns - self.clock.now_ns()) / 1e9 / self.clock.speed
            if wait <= 0:
                return None
            self.stop.wait(min(wait, POLL_S))
        return None

    def _hold(self, a: Anchor, anchors: list[Anchor],
              i: int) -> tuple[LiveEvent | None, tuple[int, LiveEvent] | None]:
        """At a recorded anchor: wait for the live event, repeating the stream keys' last message.

        Returns (the live event of this anchor, None), or (None, (j, event)) when the live
        conductor is already at a later anchor j, or (None, None) on timeout or stop.
        """
        assert self.clock is not None
        t0 = time.monotonic()
        held = False
        period_s = self.hand_period_ns / 1e9 / self.clock.speed
        next_repeat = t0 + period_s
        while not self.stop.is_set():
            taken = self._take_live(anchors, i)
            if taken is not None:
                j, ev = taken
                if held:
                    self.stats.hold_s += time.monotonic() - t0
                return (ev, None) if j == i else (None, (j, ev))
            if not held and time.monotonic() - t0 > POLL_S:
                held = True
                self.stats.holds += 1
            if time.monotonic() - t0 > self.follow_timeout_s:
                log.warning("no live %s of trial %d within %.0f s: going on without it",
                            a.phase, a.trial, self.follow_timeout_s)
                self._delta = self.clock.now_ns() - a.t_ns
                return None, None
            if time.monotonic() >= next_repeat:
                self._repeat_streams()
                next_repeat += period_s
            self.stop.wait(POLL_S)
        return None, None

    def _repeat_streams(self) -> None:
        """Send the last message of each stream key again, stamped now (the rig stays fresh)."""
        assert self.clock is not None
        now = self.clock.now_ns()
        for topic, msg in list(self._last_msg.items()):
            if TOPICS[topic].qos.congestion == "drop":
                self._send_restamped(topic, msg, now)
                self.stats.repeated += 1

    def _hold_until_the_end(self) -> None:
        """After the last recorded message: keep the rig fresh until the live session ends."""
        assert self.clock is not None and self.follow is not None
        t0 = time.monotonic()
        period_s = self.hand_period_ns / 1e9 / self.clock.speed
        while not self.stop.is_set() and not self.live_ended:
            self._take_live([], 0)
            if time.monotonic() - t0 > self.follow_timeout_s:
                log.warning("the live session did not end within %.0f s of the recording's end",
                            self.follow_timeout_s)
                return
            self._repeat_streams()
            self.stop.wait(period_s)
