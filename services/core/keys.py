"""Key expressions: `nod/<rig>/<service>/<topic>`, defined once for every service.

Scoping every key by rig lets several rigs (or labs) share one Zenoh network without crosstalk,
and lets ACLs be written per service.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from services.core import messages as m

_RIG_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")

# topic -> (message type, publisher, subscribers, rate) — the README's contract table is this.
TOPICS: dict[str, tuple[type[m.Message], str, str, str]] = {
    "vision/hand": (m.HandPose, "vision | sim", "decision, actuation, experiment", "30 Hz"),
    "vision/layout": (m.Layout, "vision | sim", "decision, actuation, experiment", "1 Hz + query"),
    "vision/frame": (m.VisionFrame, "vision", "monitor", "2 Hz (--frames-key-hz)"),
    "sim/camera": (m.VisionFrame, "sim --render", "vision --source zenoh:sim/camera", "30 Hz"),
    "decision/z_h": (m.Scalar, "decision", "experiment, sim, monitor", "per hand pose"),
    "decision/z_r": (m.Scalar, "decision", "actuation, experiment, sim", "per hand pose"),
    "decision/b_r": (m.Scalar, "decision", "experiment, monitor", "per hand pose"),
    "actuation/cmd": (m.ArmCommandMsg, "actuation", "monitor", "on change + 10 Hz"),
    "actuation/state": (m.ArmStateMsg, "actuation", "sim, experiment, monitor", "50 Hz"),
    "actuation/press": (m.PressMsg, "actuation", "experiment", "once per trial"),
    "eyes/cmd": (m.GazeMsg, "experiment", "eyes, sim", "per trial + 5 Hz keepalive"),
    "eyes/state": (m.EyesStateMsg, "eyes", "monitor", "on change + 5 Hz"),
    "experiment/trial": (m.TrialEvent, "experiment", "decision, actuation, sim", "per event"),
    "experiment/result": (m.TrialResult, "experiment", "monitor", "per trial"),
    "safety/estop": (m.Estop, "anyone (`nod estop`)", "actuation, eyes", "on demand"),
}


def check_rig(rig: str) -> str:
    """Validate a rig name (it becomes one key chunk): letters, digits, '-' and '_'."""
    if not _RIG_RE.match(rig):
        raise ValueError(f"rig name {rig!r} must be 1-64 letters, digits, '-' or '_'")
    return rig


@dataclass(frozen=True, slots=True)
class Keys:
    """All key expressions of one rig."""

    rig: str = "rig1"

    def __post_init__(self) -> None:
        check_rig(self.rig)

    def topic(self, topic: str) -> str:
        """The full key of a topic, e.g. `nod/rig1/vision/hand`."""
        if topic not in TOPICS:
            raise KeyError(f"unknown topic {topic!r}; known: {sorted(TOPICS)}")
        return f"nod/{self.rig}/{topic}"

    def alive(self, service: str) -> str:
        """The liveliness token key of a service instance."""
        return f"nod/{self.rig}/alive/{service}"

    @property
    def all(self) -> str:
        """Every key of the rig (for monitors and recorders)."""
        return f"nod/{self.rig}/**"

    def message_type(self, key: str) -> type[m.Message] | None:
        """The message type carried on a full key of this rig, or None."""
        prefix = f"nod/{self.rig}/"
        topic = key[len(prefix) :] if key.startswith(prefix) else ""
        return TOPICS[topic][0] if topic in TOPICS else None
