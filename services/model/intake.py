"""Bounded intake: how many messages of a kind a service keeps, whatever a peer sends.

`IntakeLimit` is a token bucket (a burst of `burst`, then `per_s` a second) with two hard caps:
`per_scope` messages in one scope (a trial attempt: whatever it is, the caller names it) and
`total` in all (a session). It is clock-free: the caller passes a monotonic time in ns, so a
test can drive it with any clock. Integers throughout: over any window of `t` seconds it admits
at most `burst + per_s · t` messages, exactly, and counts every one it refuses.
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass, field

NS_PER_S = 1_000_000_000


@dataclass
class IntakeLimit:
    """A token bucket with a cap per scope and a cap in all; `admit` says yes or why not."""

    burst: int  # messages admitted back to back after a quiet spell; >= 1
    per_s: int  # sustained rate once the burst is spent (messages per second); >= 0
    per_scope: int  # at most this many in one scope (e.g. a trial attempt); >= 0
    total: int  # at most this many in all (e.g. a session); >= 0
    scope_label: str = "per scope"  # how the reasons and `describe` name the caps
    total_label: str = "in all"
    accepted: int = 0
    dropped: int = 0
    # The bucket in 1e-9 tokens: exact integer refill of `per_s` units per ns.
    _level: int = field(default=0, init=False, repr=False)
    _last_ns: int | None = field(default=None, init=False, repr=False)
    _scope: Hashable = field(default=None, init=False, repr=False)
    _in_scope: int = field(default=0, init=False, repr=False)
    # The reasons `admit` gives and `describe`, written once (a flood asks for them per message).
    _why_total: str = field(default="", init=False, repr=False)
    _why_scope: str = field(default="", init=False, repr=False)
    _why_rate: str = field(default="", init=False, repr=False)
    _description: str = field(default="", init=False, repr=False)

    def __post_init__(self) -> None:
        if self.burst < 1 or self.per_s < 0 or self.per_scope < 0 or self.total < 0:
            raise ValueError(
                f"intake limit needs burst >= 1 and per_s, per_scope, total >= 0, got {self}"
            )
        self._level = self.burst * NS_PER_S  # full: the first burst passes at once
        self._why_total = f"cap of {self.total} {self.total_label}"
        self._why_scope = f"cap of {self.per_scope} {self.scope_label}"
        self._why_rate = f"rate limit (burst {self.burst}, {self.per_s}/s)"
        self._description = (
            f"burst {self.burst}, then {self.per_s}/s; {self.per_scope} {self.scope_label}; "
            f"{self.total} {self.total_label}"
        )

    def admit(self, now_ns: int, scope: Hashable = None) -> str | None:
        """Take one message arriving at `now_ns` (monotonic) in `scope`: None, or why it is dropped.

        A time before the last one refills nothing (the bucket never runs backwards). A refused
        message spends no token, so the caps and the rate are independent.
        """
        if self._last_ns is not None and now_ns > self._last_ns:
            elapsed = now_ns - self._last_ns
            self._level = min(self.burst * NS_PER_S, self._level + self.per_s * elapsed)
        if self._last_ns is None or now_ns > self._last_ns:
            self._last_ns = now_ns
        if scope != self._scope:
            self._scope, self._in_scope = scope, 0
        why = None
        if self.accepted >= self.total:
            why = self._why_total
        elif self._in_scope >= self.per_scope:
            why = self._why_scope
        elif self._level < NS_PER_S:
            why = self._why_rate
        if why is not None:
            self.dropped += 1
            return why
        self._level -= NS_PER_S
        self._in_scope += 1
        self.accepted += 1
        return None

    def describe(self) -> str:
        """The limits in one line: "burst 50, then 2/s; 200 per scope; 1000 in all"."""
        return self._description
