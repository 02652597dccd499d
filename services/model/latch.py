"""The e-stop latch: what an engaged e-stop is, and the only thing that lifts it.

Pure: the device shells persist a `Latch` to a file on their host and answer for it on the
fabric (`services/safety/latch_file.py`, `services/safety/wiring.py`); this module only decides.

- An engage is always obeyed, whatever its id: stopping is never the unsafe direction.
- A release lifts the latch only if its id is fresh: not empty, neither the id of the engage
  it lifts nor one of the recent commands this device obeyed. A replayed release (a recording
  played back onto the fabric, a stuck repeater) cannot lift a later e-stop.
- A repeat of the command just obeyed (`nod estop` repeats until acknowledged) changes nothing.
- What several holders say is merged conservatively (`merge`): engaged if any holder is
  engaged. A device that comes back after being down through a release therefore stays
  engaged until it hears a release of its own — the operator sees it on its state key and
  releases again — rather than lifting an e-stop nobody lifted for it.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Literal

Verdict = Literal["obeyed", "repeat", "refused"]
MAX_SEEN = 64  # recent command ids remembered per device (a few hours of an operator's e-stops)
ID_CHARS = 64  # longest command id kept
TEXT_CHARS = 200  # longest reason/source kept


@dataclass(frozen=True, slots=True)
class Latch:
    """The e-stop state of one device: engaged or not, the command that made it so."""

    engaged: bool = False
    reason: str = ""
    source: str = ""
    id: str = ""  # the last command obeyed (acknowledged on the state keys)
    seen: tuple[str, ...] = ()  # ids of recent commands obeyed, oldest first, at most MAX_SEEN

    def command(
        self, engaged: bool, reason: str, source: str, command_id: str
    ) -> tuple[Latch, Verdict]:
        """An e-stop command (engage or release): the new latch and what became of the command."""
        command_id = command_id[:ID_CHARS]
        if engaged == self.engaged and command_id == self.id:
            return self, "repeat"
        if not engaged and (not command_id or command_id in self.seen):
            return self, "refused"  # no id, or one already used (replayed, the engage's own id)
        if not engaged and not self.engaged:
            # Released already: note the id (so it cannot be replayed later), nothing else moves.
            return replace(self, id=command_id, seen=_remember(self.seen, command_id)), "obeyed"
        return (
            Latch(engaged, reason[:TEXT_CHARS], source[:TEXT_CHARS], command_id,
                  _remember(self.seen, command_id)),
            "obeyed",
        )


def merge(own: Latch, others: Iterable[Latch]) -> Latch:
    """The latch a device takes on at start: its own, engaged if any other holder is engaged.

    An engaged holder's command is adopted (its reason and id) when this device's own latch is
    released; the ids every holder has seen are remembered, so none of them can release it.
    """
    merged = own
    for other in others:
        seen = merged.seen
        for cid in other.seen:
            seen = _remember(seen, cid)
        if other.engaged and not merged.engaged:
            merged = Latch(True, other.reason, other.source, other.id, _remember(seen, other.id))
        else:
            merged = replace(merged, seen=seen)
    return merged


def _remember(seen: tuple[str, ...], command_id: str) -> tuple[str, ...]:
    if not command_id or command_id in seen:
        return seen
    return (*seen, command_id)[-MAX_SEEN:]
