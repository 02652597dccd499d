"""Key expressions: `nod/<rig>/<service>/<topic>`, defined once for every service.

Scoping every key by rig lets several rigs (or labs) share one Zenoh network without crosstalk,
and lets ACLs be written per service.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from services.core import messages as m
from services.core.contract import TOPICS

_RIG_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")

def topic_of(key: str) -> str | None:
    """The contract topic of a full key of any rig (`nod/<rig>/<topic>`), or None."""
    parts = key.split("/", 2)
    if len(parts) == 3 and parts[0] == "nod" and parts[2] in TOPICS:
        return parts[2]
    return None


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

    def topic_of(self, key: str) -> str | None:
        """The topic name of a full key of this rig (e.g. `vision/hand`), or None."""
        prefix = f"nod/{self.rig}/"
        topic = key[len(prefix) :] if key.startswith(prefix) else ""
        return topic if topic in TOPICS else None

    def alive(self, service: str) -> str:
        """The liveliness token key of a service instance."""
        return f"nod/{self.rig}/alive/{service}"

    @property
    def all(self) -> str:
        """Every key of the rig (for monitors and recorders)."""
        return f"nod/{self.rig}/**"

    def message_type(self, key: str) -> type[m.Message] | None:
        """The message type carried on a full key of this rig, or None."""
        topic = self.topic_of(key)
        return TOPICS[topic].message if topic is not None else None
