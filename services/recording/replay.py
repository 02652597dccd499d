"""`nod replay FILE.mcap`: play a recording back onto a rig, or re-run the decision model on it.

Three ways to play:

- Plain (default): each message's original payload bytes, on its key (rewritten to `--rig` if
  given; default the recording's rig), at the original inter-message timing (`log_time`, the
  recorder's wall clock) divided by `--speed`. For viewers (`nod monitor`, `nod topic`) and
  for services started on a clock that matches the recording's stamps.
- `--restamp`: each message re-encoded with `t_ns` moved onto the live rig clock (`--clock-speed`,
  `--epoch-ns`: the values the rig's services were given; a real rig's wall clock by default)
  and `seq` renumbered per key, sent when the rig clock reads that stamp. Live services judge
  freshness and clock skew by `t_ns`, so a replay into running services needs this.
- `--follow` (implies `--restamp`): the live conductor (`nod experiment`) drives the protocol,
  and the replay follows it. At each recorded trial "setup" and "go" the replay waits for the
  live conductor's same event (repeating the last hand pose meanwhile, restamped, so the rig
  stays fresh) or skips ahead to it, and moves its clock offset there: each trial's recorded
  hand path starts at the live "go" exactly as it started at the recorded one. With
  `--inputs`, a fresh decision/actuation/eyes/experiment then replays the recorded session.

What `--inputs` replays (derived from the contract, `input_topics()`): the keys that some
service under test (decision, actuation, eyes, experiment) subscribes to and none of them
publishes — `vision/hand` and `vision/layout` — less `rig/event` (the recorded launcher's
account of its processes: replayed, it would interrupt trials for crashes that are not
happening) and `safety/*` (operator acts: an e-stop replayed would hold the rig, and a release
is never replayed from a file — it could release an e-stop engaged live; `safety/release` is
left out of every replay unless named with `--only`). A replay of vision keys holds the
`vision` liveliness token, as the sim participant does, so the services that require vision
accept it.

`--through decision [--params P] --out FILE2` runs offline, no Zenoh: the recorded
vision/hand, vision/layout and experiment/trial messages go in order through `DecisionModel`
(reset on setup/go with `DecisionModel.on_trial`, like the decision service), and FILE2 is the
recording without its decision/* channels plus the recomputed decision/z_r, z_h and b_r (same
keys, encoded with the project's encoder, stamped with the pose's `t_ns`, logged at the pose's
log time). One line per trial compares the final z_r and b_r, recorded vs recomputed.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import queue
import statistics
import sys
import threading
import time
import tomllib
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
import zenoh

from services.core import messages as m
from services.core.cli import Parser, add_params_arg, positive_float
from services.core.clock import Clock
from services.core.config import from_mapping, load_toml
from services.core.contract import TOPICS
from services.core.keys import Keys
from services.core.node import declare_publisher, install_signal_handlers, setup_logging
from services.core.session import Fabric, add_zenoh_args, open_session
from services.model.decision import DecisionModel
from services.model.params import NodConfig
from services.recording.mcap_io import (
    END_METADATA,
    FILE_METADATA,
    SESSION_METADATA,
    Entry,
    McapIn,
    McapOut,
    rig_of,
    topic_of,
)
from services.recording.record import one_line

PROG = "nod replay"
log = logging.getLogger("nod.replay")
UNDER_TEST = ("decision", "actuation", "eyes", "experiment")
NOT_INPUTS = {
    "rig/event": "the recorded launcher's account of its processes: replayed, it would "
    "interrupt trials for crashes that are not happening",
    "safety/estop": "an operator's act: replayed without its release it holds the rig",
    "safety/release": "an operator's act, never replayed from a file: it could release an "
    "e-stop engaged live",
}
NEVER_UNLESS_NAMED = ("safety/release",)
DECISION_TOPICS = ("decision/z_r", "decision/z_h", "decision/b_r")
ANCHOR_PHASES = ("setup", "go")
END_PHASES = ("session_end", "abort")
POLL_S = 0.005  # a waiting player looks at the live events this often


def input_topics() -> tuple[str, ...]:
    """The keys a fresh decision/actuation/eyes/experiment need from outside (see the module)."""
    under = set(UNDER_TEST)
    return tuple(
        t.name for t in TOPICS.values()
        if under & set(t.subscribers) and not under & set(t.publishers)
        and t.name not in NOT_INPUTS
    )


def select_topics(available: Iterable[str], only: list[str] | None, inputs: bool) -> set[str]:
    """The contract topics to replay among those in the file."""
    topics = {t for t in available if not (t in TOPICS and TOPICS[t].queried_only)}
    if inputs:
        topics &= set(input_topics())
    if only:
        chosen = set()
        for pattern in only:
            text = pattern.strip().strip("/")
            if text.startswith("nod/"):  # a full key: its topic part, whatever the rig
                text = text.split("/", 2)[2] if text.count("/") >= 2 else ""
            try:
                expr = zenoh.KeyExpr(text)
            except zenoh.ZError:
                raise ValueError(f"--only {pattern!r} is not a key expression") from None
            chosen |= {t for t in topics if expr.intersects(zenoh.KeyExpr(t))}
        topics = chosen
    else:
        topics -= set(NEVER_UNLESS_NAMED)
    return topics


# --- the recording's protocol events --------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Anchor:
    """A recorded trial event the follower waits for: where it is in the file, and its stamp."""

    index: int  # position of the event among the file's messages
    phase: str
    trial: int
    t_ns: int


@dataclass
class Scan:
    """What one pass over a recording finds: its rig, topics, protocol events, camera period."""

    rig: str | None = None
    topics: set[str] = field(default_factory=set)
    anchors: list[Anchor] = field(default_factory=list)
    hand_period_ns: int = 33_333_333
    messages: int = 0
    truncated: str | None = None
    meta: dict[str, str] = field(default_factory=dict)


def scan(src: McapIn) -> Scan:
    """One pass over the file: keys, anchors (setup/go events), the hand poses' period."""
    out = Scan()
    hand_t: list[int] = []
    for e in src:
        out.messages += 1
        topic = topic_of(e.key)
        if topic is None or not e.valid:
            continue
        out.topics.add(topic)
        if out.rig is None:
            out.rig = rig_of(e.key)
        if topic == "experiment/trial":
            ev = _decode(topic, e)
            if ev is not None and ev.phase in ANCHOR_PHASES:
                out.anchors.append(Anchor(e.index, ev.phase, ev.trial, ev.t_ns))
        elif topic == "vision/hand" and len(hand_t) < 2000:
            hand_t.append(e.message.publish_time)
    gaps = [b - a for a, b in zip(hand_t, hand_t[1:], strict=False) if b > a]
    if gaps:
        out.hand_period_ns = int(statistics.median(gaps))
    out.truncated = src.truncated
    out.meta = src.file_metadata()
    out.rig = out.meta.get("rig") or out.rig
    return out


def _decode(topic: str, e: Entry) -> Any:
    try:
        return m.decode(TOPICS[topic].message, e.message.data)
    except m.MessageError:
        return None


# --- playing onto a rig ---------------------------------------------------------------------------


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
            msg = _decode(topic, e)
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
        self._pub(topic).put(e.message.data)
        self._note(time.monotonic() - due)

    def _skip(self, topic: str, e: Entry, skipped_last: dict[str, tuple[m.Message, int]]) -> None:
        """A message passed over while catching up; the last one of a state key is kept."""
        self.stats.skipped += 1
        if TOPICS[topic].qos.congestion == "block":  # state (the layout): its latest value counts
            msg = _decode(topic, e)
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


# --- offline: the decision model over a recording -------------------------------------------------


@dataclass
class TrialComparison:
    """One trial's decision outputs, recorded vs recomputed, at the last pose both answered."""

    trial: int
    mode: str = ""
    option: str | None = None
    recorded: dict[int, tuple[float, float]] = field(default_factory=dict)  # src_seq → (z_r, b_r)
    recomputed: dict[int, tuple[float, float]] = field(default_factory=dict)
    robot: str | None = None
    human: str | None = None
    outcome: str | None = None
    closed: bool = False

    def final(self) -> tuple[tuple[float, float] | None, tuple[float, float] | None]:
        """(recorded, recomputed) (z_r, b_r) at the last pose of the trial both have."""
        common = set(self.recorded) & set(self.recomputed)
        if common:
            seq = max(common)
            return self.recorded[seq], self.recomputed[seq]
        rec = self.recorded[max(self.recorded)] if self.recorded else None
        new = self.recomputed[max(self.recomputed)] if self.recomputed else None
        return rec, new

    def line(self) -> str:
        """`trial 5 consensus O=red: z_r +0.41 → -0.22 (red → blue), b_r ...; recorded: ...`."""
        rec, new = self.final()

        def fmt(v: tuple[float, float] | None, i: int) -> str:
            return "—" if v is None else f"{v[i]:+.3f}"

        def side(v: tuple[float, float] | None) -> str:
            return "?" if v is None else ("red" if v[0] > 0 else "blue" if v[0] < 0 else "0")

        option = f" O={self.option}" if self.option else ""
        return (
            f"trial {self.trial} {self.mode}{option}: z_r {fmt(rec, 0)} → {fmt(new, 0)} "
            f"({side(rec)} → {side(new)}), b_r {fmt(rec, 1)} → {fmt(new, 1)}; recorded: robot "
            f"{self.robot or '—'}, human {self.human or '—'}, outcome {self.outcome or '—'}"
        )


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def decision_config(meta: dict[str, str], params: Path | None) -> NodConfig:
    """The recording's parameters (its `params_toml`, if it has one), overridden by `params`."""
    base: dict[str, Any] = {}
    if meta.get("params_toml"):
        base = tomllib.loads(meta["params_toml"])
    over = load_toml(params) if params is not None else {}
    return from_mapping(NodConfig, _merge(base, over))


@dataclass
class ThroughResult:
    """What `--through decision` did."""

    trials: list[TrialComparison]
    poses: int
    recomputed: int
    left_out: int
    messages: int


def through_decision(src_path: Path, out_path: Path, params: Path | None) -> ThroughResult:
    """Re-run the decision model on a recording; write it with the recomputed outputs."""
    src = McapIn(src_path)
    meta = src.file_metadata()
    cfg = decision_config(meta, params)
    model = DecisionModel(cfg.decision, cfg.layout)
    out = McapOut(out_path)
    derived = {**meta, "derived_from": str(src_path), "through": "decision"}
    if params is not None:
        derived["through_params_file"] = str(params)
        derived["through_params_toml"] = Path(params).read_text(encoding="utf-8")
    out.metadata(FILE_METADATA, derived)
    seq = dict.fromkeys(DECISION_TOPICS, 0)
    trials: dict[int, TrialComparison] = {}
    current: TrialComparison | None = None
    poses = recomputed = left_out = 0
    try:
        for e in src:
            topic = topic_of(e.key)
            if topic in DECISION_TOPICS:
                left_out += 1
                open_trial = current is not None and not current.closed
                if e.valid and open_trial and topic != "decision/z_h":
                    msg = _decode(topic, e)
                    if msg is not None:
                        z_r, b_r = current.recorded.get(msg.src_seq, (math.nan, math.nan))
                        current.recorded[msg.src_seq] = (
                            (msg.value, b_r) if topic == "decision/z_r" else (z_r, msg.value)
                        )
                continue
            out.write(out.copy_channel(e.channel, e.schema), e.message.log_time,
                      e.message.publish_time, e.message.data, e.message.sequence)
            if topic is None or not e.valid:
                continue
            msg = _decode(topic, e)
            if msg is None:
                continue
            if isinstance(msg, m.TrialEvent):
                try:
                    model.on_trial(msg.phase, msg.mode, msg.option)
                except ValueError as exc:  # the decision service refuses such an event too
                    log.warning("trial event refused: %s", exc)
                if msg.phase == "setup":
                    current = trials[msg.trial] = TrialComparison(msg.trial, msg.mode, msg.option)
                elif msg.phase in ("end", "interrupted") and current is not None:
                    current.closed = True
            elif isinstance(msg, m.TrialResult) and msg.trial in trials:
                t = trials[msg.trial]
                t.robot, t.human, t.outcome = msg.robot, msg.human, msg.outcome
            elif isinstance(msg, m.Layout):
                try:
                    model.set_layout(m.layout_from_msg(msg))
                except ValueError as exc:
                    log.warning("layout refused: %s", exc)
            elif isinstance(msg, m.HandPose):
                poses += 1
                if not model.accepts(msg.t_ns):
                    continue
                res = model.on_hand(msg.t_ns, msg.landmarks if msg.detected else None)
                prefix = e.key[: -len("vision/hand")]
                obs = res.observation
                for name, value in (
                    ("decision/z_r", m.Scalar(seq=seq["decision/z_r"], t_ns=msg.t_ns,
                                              value=res.z_r, src_seq=msg.seq)),
                    ("decision/z_h", m.Observed(seq=seq["decision/z_h"], t_ns=msg.t_ns,
                                                value=res.z_hat, src_seq=msg.seq,
                                                theta=obs.theta, distance=obs.distance)),
                    ("decision/b_r", m.Scalar(seq=seq["decision/b_r"], t_ns=msg.t_ns,
                                              value=res.b_r, src_seq=msg.seq)),
                ):
                    seq[name] += 1
                    out.write(out.channel(prefix + name), e.message.log_time, msg.t_ns,
                              m.encode(value), value.seq)
                    recomputed += 1
                if current is not None and not current.closed:
                    current.recomputed[msg.seq] = (res.z_r, res.b_r)
        for name, data in src.metadata:
            if name == SESSION_METADATA:
                out.metadata(name, dict(data))
        out.metadata(END_METADATA, {"messages": str(out.messages), "source_truncated":
                                    src.truncated or ""})
    finally:
        out.finish()
    return ThroughResult(sorted(trials.values(), key=lambda t: t.trial), poses, recomputed,
                         left_out, out.messages)


# --- the command line -----------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod replay`."""
    p = Parser(
        prog=PROG,
        description="Play a recording (nod record) back onto a rig, or re-run the decision "
        "model on it offline (--through decision).",
    )
    p.add_argument("file", type=Path, metavar="FILE.mcap", help="the recording")
    add_zenoh_args(p)
    p.set_defaults(rig=None)
    p.add_argument("--speed", type=positive_float, default=1.0, metavar="X",
                   help="play X times as fast as recorded (plain replays; default 1)")
    p.add_argument("--only", action="append", default=None, metavar="KEY",
                   help="replay only this key (e.g. vision/hand, 'vision/*'); repeatable")
    p.add_argument("--inputs", action="store_true",
                   help="replay only what a fresh decision/actuation/eyes/experiment need from "
                   "outside: " + ", ".join(input_topics()))
    p.add_argument("--loop", action="store_true", help="start over at the end, until Ctrl-C")
    p.add_argument("--restamp", action="store_true",
                   help="move every t_ns onto the live rig clock and renumber seq (for live "
                   "services)")
    p.add_argument("--follow", action="store_true",
                   help="follow the live conductor: meet it at each trial's setup and go "
                   "(implies --restamp)")
    p.add_argument("--follow-timeout", type=positive_float, default=60.0, metavar="S",
                   help="how long to wait for the live conductor at a trial event (60 s)")
    clock = p.add_argument_group("the live rig's clock (--restamp, --follow)")
    clock.add_argument("--clock-speed", type=positive_float, default=1.0, metavar="S",
                       help="the rig's simulated seconds per wall second (its services' --speed)")
    clock.add_argument("--epoch-ns", type=int, default=None,
                       help="the rig's clock epoch (its services' --epoch-ns)")
    off = p.add_argument_group("offline (no Zenoh)")
    off.add_argument("--through", choices=("decision",), default=None,
                     help="re-run this model over the recording and write --out")
    off.add_argument("--out", type=Path, default=None, metavar="FILE2.mcap",
                     help="the recording written by --through")
    add_params_arg(p)
    p.add_argument("-v", "--verbose", action="store_true", help="log at debug level")
    return p


def main(argv: list[str] | None = None) -> int:
    """Replay, or re-run the decision model; 2 on bad flags, an unreadable file or no router."""
    parser = build_parser()
    args = parser.parse_args(argv)
    setup_logging(args.verbose)
    problem = _check(args)
    if problem:
        print(f"{PROG}: {problem}", file=sys.stderr)
        return 2
    try:
        if args.through is not None:
            return _through(args)
        return _replay(args)
    except (ValueError, OSError) as exc:
        print(f"{PROG}: {one_line(str(exc))}", file=sys.stderr)
        return 2


def _check(args: argparse.Namespace) -> str | None:
    if args.through is not None:
        if args.out is None:
            return "--through needs --out FILE2.mcap"
        if args.out.resolve() == args.file.resolve():
            return "--out must be another file than the recording"
        return None
    if args.out is not None or args.params is not None:
        return "--out and --params go with --through"
    if args.follow and args.loop:
        return "--follow plays one session: it does not --loop"
    if (args.restamp or args.follow) and args.speed != 1.0:
        return ("a restamped replay runs on the live rig's clock (--clock-speed); --speed is "
                "for plain replays")
    return None


def _through(args: argparse.Namespace) -> int:
    res = through_decision(args.file, args.out, args.params)
    for t in res.trials:
        print(t.line())
    print(
        f"{PROG}: wrote {args.out}: {res.messages} messages; decision/z_r, z_h, b_r recomputed "
        f"from {res.poses} hand poses ({res.recomputed} messages), {res.left_out} recorded "
        "decision messages left out",
        flush=True,
    )
    return 0


def _replay(args: argparse.Namespace) -> int:
    src = McapIn(args.file)
    found = scan(src)
    if found.truncated:
        log.warning("%s: %s; replaying what precedes it", args.file, found.truncated)
    topics = select_topics(found.topics, args.only, args.inputs)
    if not topics:
        raise ValueError(f"nothing to replay: the file holds {sorted(found.topics) or 'no keys'}")
    rig = args.rig or found.rig or "rig1"
    args.rig = rig
    restamp = args.restamp or args.follow
    if args.follow and not found.anchors:
        raise ValueError("--follow needs the recording's experiment/trial events; it has none")
    stop = threading.Event()
    install_signal_handlers(stop)
    session = open_session(Fabric.from_args(args).zenoh_config())
    keys = Keys(rig)
    tokens = []
    live = None
    try:
        if any(t.startswith("vision/") for t in topics):  # stand in for vision, like the sim
            tokens.append(session.liveliness().declare_token(keys.alive("vision")))
        if args.follow:
            live = LiveEvents(session, keys)
        player = Player(
            session, rig, topics, stop,
            speed=args.speed,
            clock=Clock(args.clock_speed, args.epoch_ns) if restamp else None,
            follow=live,
            follow_timeout_s=args.follow_timeout,
            hand_period_ns=found.hand_period_ns,
        )
        print(
            f"{PROG}: {args.file} ({found.messages} messages) onto rig {rig!r}: "
            f"{', '.join(sorted(topics))}"
            + (" (restamped)" if restamp and not args.follow else "")
            + (" (following the live conductor)" if args.follow else ""),
            flush=True,
        )
        while True:
            player.play(src, found.anchors)
            if not args.loop or stop.is_set():
                break
        player.close()
    finally:
        if live is not None:
            live.close()
        for token in tokens:
            token.undeclare()
        session.close()
    print(player.stats.line(), flush=True)
    return 130 if stop.is_set() else 0


if __name__ == "__main__":
    raise SystemExit(main())
