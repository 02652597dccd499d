"""What a replay plays: which of a recording's keys, and where its trials begin.

The keys are derived from the contract; the trials' beginnings are the recorded protocol events
a following replay anchors on. `nod replay`'s module documentation says why each key is or is
not an input.
"""

from __future__ import annotations

import logging
import statistics
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from services.core import messages as m
from services.core.contract import TOPICS
from services.core.keys import topic_of
from services.recording.mcap_io import (
    Entry,
    McapIn,
    rig_of,
)

PROG = "nod replay"
log = logging.getLogger("nod.replay")
UNDER_TEST = ("decision", "actuation", "eyes", "experiment")
NOT_INPUTS = {
    "rig/event": "the recorded launcher's account of its processes: replayed, it would "
    "interrupt trials for crashes that are not happening",
    "safety/estop": "an operator's act: replayed without its release it holds the rig",
    "experiment/operator": "an operator's act: the live operator starts and holds the trials",
    "speaker/played": "the onsets of the recorded countdown: a live speaker reports those of "
    "the replayed one, and the old ones would be stored under the new trials",
    "safety/release": "an operator's act, never replayed from a file: it could release an "
    "e-stop engaged live",
    "estimate/person": "the recorded session's estimates of its person: a live `nod estimate` "
    "gives the replayed session's own, and the old ones would be stored under it",
}
NEVER_UNLESS_NAMED = ("safety/release",)
ANCHOR_PHASES = ("setup", "go")
END_PHASES = ("session_end", "abort")


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
            ev = decode_entry(topic, e)
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


def decode_entry(topic: str, e: Entry) -> Any:
    """A recorded message decoded as its topic's type (None if it is not valid)."""
    try:
        return m.decode(TOPICS[topic].message, e.payload)
    except m.MessageError:
        return None
