"""`nod monitor --from FILE.mcap`: a recording shown as the live monitor shows a rig.

Rerun opens MCAP files itself but decodes only ROS 2 and Protobuf messages; a recording's JSON
channels (`services.recording.json_channels`) would show there as raw records. This feeds every
valid message of a recording, in file order, through the monitor's own `RerunBridge`, stamped
with its `t_ns` as live, into the monitor's sinks (`--save FILE.rrd`, a viewer, the web viewer):
the same entities as a live session, so the blueprint attached to the recording
(`rerun-blueprint.rbl`) and the monitor's own lay it out. Older (msgpack) recordings too: the
messages come from `Entry.payload`, like every reader's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from services.core.keys import topic_of
from services.monitor.bridge import NOT_SHOWN, RerunBridge
from services.recording.mcap_io import McapIn
from services.recording.selection import decode_entry


@dataclass(frozen=True, slots=True)
class Shown:
    """What went through the bridge, what did not decode, and why the file ended early."""

    logged: int
    undecodable: int
    truncated: str | None


def log_recording(bridge: RerunBridge, path: Path) -> Shown:
    """Every valid message of the recording at `path` through `bridge`, in file order."""
    src = McapIn(path)
    undecodable = 0
    for e in src:
        topic = topic_of(e.key)
        if topic is None or not e.valid or topic in NOT_SHOWN:
            continue
        msg = decode_entry(topic, e)
        if msg is None:
            undecodable += 1
            continue
        bridge.log(topic, msg)
    return Shown(bridge.logged, undecodable, src.truncated)
