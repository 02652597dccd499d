"""One holder of a role per rig: a claim made before anything else, and noticed if another comes.

The conductor's `alive/experiment` token is declared only once it has heard the devices (up to
5 s): a second conductor started in that window saw nobody, and both ran the protocol. A claim
is a liveliness token of its own, `nod/<rig>/alive/<role>/claim/<id>`, declared first thing;
its id orders claims by when they were made (wall ns, then pid and a random tag). After
`SETTLE_S` — longer than a token takes to reach the router and come back in a query — each
claimant asks for every claim of the role: whoever finds an earlier claim than its own gives
way. Two conductors started within a second of each other therefore both see both claims and
agree on the earlier one; one started later finds the first already there.

The claim then stays watched: a claim that appears later (a host whose clock is behind, a
network that healed) is reported to `on_rival`, so the holder can hold its trial and say so.
"""

from __future__ import annotations

import logging
import os
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

log = logging.getLogger(__name__)
SETTLE_S = 0.5  # a token's round trip through the router, with room for a loaded host
ASK_S = 1.0  # how long the query for the other claims may take
GONE_S = 2.0  # how long a holder killed a moment ago may still look present (the router's view)


class RigTakenError(RuntimeError):
    """Another process made an earlier claim of the role on this rig."""


def claim_prefix(rig: str, role: str) -> str:
    """Where the claims of a role on a rig live."""
    return f"nod/{rig}/alive/{role}/claim"


def new_claim_id(now_ns: int | None = None) -> str:
    """A claim id that orders by when it was made: `<wall ns, 19 digits>-<pid>-<tag>`."""
    t = time.time_ns() if now_ns is None else now_ns
    return f"{t:019d}-{os.getpid()}-{secrets.token_hex(3)}"


def earliest(ids: list[str]) -> str:
    """The claim that holds the role: the earliest made (ids order by time)."""
    return min(ids)


@dataclass
class Claim:
    """A process's claim of a role on a rig (see the module doc); `release()` ends it."""

    session: zenoh.Session
    rig: str
    role: str
    on_rival: Callable[[str, bool], None] = lambda _claim, _present: None
    label: str = ""  # what the role is called in messages (default: the role)
    id: str = field(default_factory=new_claim_id)
    _handles: list[Any] = field(default_factory=list)
    _rivals: set[str] = field(default_factory=set)
    _active: bool = False  # the claim was taken: rivals are reported from now on
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def take(
        self, settle_s: float = SETTLE_S, grace_s: float = GONE_S,
        stop: threading.Event | None = None,
    ) -> None:
        """Declare the claim, wait `settle_s`, give way (RigTakenError) if an earlier one stays.

        An earlier claim may be a holder killed a moment ago whose token the router has not
        dropped yet (a supervisor restarting its conductor): it has `grace_s` to go. On success
        the other claims are watched from now on (`on_rival`).
        """
        waiting = stop or threading.Event()
        prefix = claim_prefix(self.rig, self.role)
        # Watched from before the claim is made: a claim that comes between the query below and
        # a later subscription would never be seen.
        self._handles.append(self.session.liveliness().declare_subscriber(
            f"{prefix}/*", self._on_change, history=False))
        self._handles.append(self.session.liveliness().declare_token(f"{prefix}/{self.id}"))
        waiting.wait(settle_s)
        deadline = time.monotonic() + grace_s
        others = self.others()
        while (others and earliest([*others, self.id]) != self.id
               and time.monotonic() < deadline and not waiting.wait(0.1)):
            others = self.others()
        if others and earliest([*others, self.id]) != self.id:
            first = earliest(others)
            self.release()
            who = self.label or self.role
            raise RigTakenError(
                f"another {who} is running on rig {self.rig!r} (it claimed the rig first: "
                f"{first}, {_age(first)} ago): one rig, one {who} — stop it first, or use "
                "another --rig"
            )
        with self._lock:
            self._active = True
            self._rivals.update(others)
            present = sorted(self._rivals)
        for other in present:  # later claimants give way by themselves; said meanwhile
            log.warning("another %s claims rig %r (claim %s)", self.label or self.role,
                        self.rig, other)
            self.on_rival(other, True)

    def others(self) -> list[str]:
        """The ids of every other claim of the role that the router knows of now."""
        prefix = claim_prefix(self.rig, self.role)
        found = []
        for reply in self.session.liveliness().get(f"{prefix}/*", timeout=ASK_S):
            if reply.ok is None:
                continue
            claim = str(reply.ok.key_expr).rsplit("/", 1)[-1]
            if claim != self.id:
                found.append(claim)
        return found

    def _on_change(self, sample: zenoh.Sample) -> None:
        claim = str(sample.key_expr).rsplit("/", 1)[-1]
        if claim != self.id:
            self._seen(claim, sample.kind == zenoh.SampleKind.PUT)

    def _seen(self, claim: str, present: bool) -> None:
        with self._lock:
            if present == (claim in self._rivals):
                return
            if present:
                self._rivals.add(claim)
            else:
                self._rivals.discard(claim)
            if not self._active:
                return
        if present:
            log.warning("another %s claims rig %r (claim %s)", self.label or self.role,
                        self.rig, claim)
        self.on_rival(claim, present)

    @property
    def rivals(self) -> set[str]:
        """The other claims present now."""
        with self._lock:
            return set(self._rivals)

    def release(self) -> None:
        """Undeclare the claim and stop watching (idempotent)."""
        for handle in self._handles:
            try:
                handle.undeclare()
            except Exception:  # best effort: the session may be closing already
                log.debug("claim handle already gone", exc_info=True)
        self._handles.clear()


def _age(claim: str) -> str:
    try:
        return f"{max(0.0, (time.time_ns() - int(claim.split('-', 1)[0])) / 1e9):.1f} s"
    except ValueError:
        return "?"
