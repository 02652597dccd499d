"""The e-stop latch: what an engaged e-stop is, and the only thing that lifts it.

Pure: the device shells persist a `Latch` to a file on their host and answer for it on the
fabric (`services/safety/latch_file.py`, `services/safety/wiring.py`); this module only decides.

- An engage is always obeyed, whatever its id: stopping is never the unsafe direction.
- A command id carries its issue order: `"<order>-<tag>"` (`new_command_id`; `nod estop` takes
  the wall clock in ns, or one past the highest order the rig's latches have seen). The latch
  keeps the highest order of every command it ever obeyed (`floor`), with it on disk and on the
  fabric. A release lifts the latch only if its order is above that floor: however many
  commands came before, no release that was ever issued earlier — a recording played back onto
  the fabric, a stuck repeater, the engage's own id — can lift a later e-stop. A bounded list
  of recent ids could not promise that (after 64 commands the oldest were forgotten).
- A repeat of the command just obeyed (`nod estop` repeats until acknowledged) changes nothing.
- What several holders say is merged conservatively (`merge`): engaged if any holder is
  engaged, the highest floor of all. A device that comes back after being down through a
  release therefore stays engaged until it hears a release of its own — the operator sees it
  on its state key and releases again — rather than lifting an e-stop nobody lifted for it.
"""

from __future__ import annotations

import re
import secrets
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Literal

Verdict = Literal["obeyed", "repeat", "refused"]
MAX_SEEN = 64  # recent command ids kept per device, for the operator's eye (not the guard)
ID_CHARS = 64  # longest command id kept
TEXT_CHARS = 200  # longest reason/source kept
MAX_ORDER = (1 << 63) - 1  # an order fits a signed 64-bit integer (msgpack, SQLite, JSON)
_ORDERED = re.compile(r"(\d{1,19})-[0-9A-Za-z_.:@]{0,40}")


def id_order(command_id: str) -> int | None:
    """The issue order a command id carries (`"<order>-<tag>"`), or None if it carries none."""
    match = _ORDERED.fullmatch(command_id)
    if match is None:
        return None
    order = int(match.group(1))
    return order if 0 < order <= MAX_ORDER else None


def new_command_id(not_before: int) -> str:
    """A fresh command id ordered at `not_before` (e.g. wall ns), with a random tag."""
    order = min(max(1, not_before), MAX_ORDER)
    return f"{order}-{secrets.token_hex(4)}"


@dataclass(frozen=True, slots=True)
class Latch:
    """The e-stop state of one device: engaged or not, the command that made it so."""

    engaged: bool = False
    reason: str = ""
    source: str = ""
    id: str = ""  # the last command obeyed (acknowledged on the state keys)
    seen: tuple[str, ...] = ()  # ids of recent commands obeyed, oldest first, at most MAX_SEEN
    floor: int = 0  # the highest order of any command ever obeyed: a release must be above it

    def command(
        self, engaged: bool, reason: str, source: str, command_id: str
    ) -> tuple[Latch, Verdict]:
        """An e-stop command (engage or release): the new latch and what became of the command."""
        command_id = command_id[:ID_CHARS]
        if engaged == self.engaged and command_id == self.id:
            return self, "repeat"
        order = id_order(command_id)
        if not engaged and (order is None or order <= self.floor):
            return self, "refused"  # unordered, or issued before a command already obeyed
        floor = max(self.floor, order or 0)
        seen = _remember(self.seen, command_id)
        if not engaged and not self.engaged:
            # Released already: note the command (it cannot be replayed later), nothing moves.
            return replace(self, id=command_id, seen=seen, floor=floor), "obeyed"
        return (
            Latch(engaged, reason[:TEXT_CHARS], source[:TEXT_CHARS], command_id, seen, floor),
            "obeyed",
        )


def merge(own: Latch, others: Iterable[Latch]) -> Latch:
    """The latch a device takes on at start: its own, engaged if any other holder is engaged.

    An engaged holder's command is adopted (its reason and id) when this device's own latch is
    released; the floor is the highest of all, so no command any holder obeyed (nor one issued
    before it) can release the merged latch.
    """
    merged = own
    for other in others:
        seen = merged.seen
        for cid in other.seen:
            seen = _remember(seen, cid)
        floor = max(merged.floor, other.floor)
        if other.engaged and not merged.engaged:
            merged = Latch(True, other.reason, other.source, other.id,
                           _remember(seen, other.id), floor)
        else:
            merged = replace(merged, seen=seen, floor=floor)
    return merged


def floor_of(seen: Iterable[str]) -> int:
    """The highest order among ids (a latch saved before floors existed)."""
    return max((o for o in map(id_order, seen) if o is not None), default=0)


def _remember(seen: tuple[str, ...], command_id: str) -> tuple[str, ...]:
    if not command_id or command_id in seen:
        return seen
    return (*seen, command_id)[-MAX_SEEN:]
