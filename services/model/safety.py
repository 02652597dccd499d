"""The safety gate of actuation and eyes: stale inputs, clock faults, lost liveliness, e-stop.

Pure and clock-free: the shell feeds it each input's *arrival* time on its own monotonic clock
(with the message's source timestamp as an offset against the rig clock), liveliness changes
and e-stop messages, and asks `check(now_ns)` on the same monotonic clock.

- Freshness is judged by arrival, never by the source timestamp: a peer's clock cannot make an
  input look fresh. A message's offset (its stamp minus the rig clock at arrival) is the
  sender's clock error minus the message's delay, and a busy 2-core host delays messages by
  100-180 ms now and then: one late message is a delay, not a clock fault. So the sender's
  clock is judged from the least-delayed message of the last `CLOCK_WINDOW_NS` (the largest
  offset, as `nod status` judges hosts): a clock behind by more than `skew_ms` is a clock fault
  within that window. A message stamped ahead of the rig clock by more than `skew_ms` (a fast
  clock, a forged stamp: no delay explains it) and one older than `skew_ms + stale_ms` (a
  replay: stale by definition) are clock faults on their own. A clock fault is counted,
  reported as a warning while recent, and the message does not refresh its input — so an
  input whose every message is skewed goes stale and stops the device, while one stray message
  among good ones does not.
- A required service counts as alive only once its liveliness token has been seen, and stops
  counting the moment it goes.
- An e-stop latches until an explicit release with a fresh id (`services.model.latch`); the
  shell persists the latch and asks its peers for theirs at start, and until it has done so
  (`adopt`) the device stays stopped: a restarted device never moves before it knows whether
  the rig's e-stop is engaged.
- A device fault (a silent, garbled or unplugged bus) stops the device like a stale input, and
  clears when the driver reports the device healthy again.
- Staleness, lost liveliness and faults clear by themselves when fresh inputs (the token, a
  healthy device) come back, because they describe the present state of the rig, not an
  operator's decision.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from services.model.latch import Latch, Verdict, merge

MAX_STALE_MS = 10_000.0  # a bound longer than this is no safety bound
MAX_SKEW_MS = 60_000.0
# The sender's clock is judged from its least-delayed message over this window (arrival clock):
# every input the gate watches sends many messages a second, so some arrive undelayed, and a
# clock that is really off is refused within it.
CLOCK_WINDOW_NS = 1_000_000_000
CLOCK_WINDOW_MESSAGES = 512  # a bound on what one input's window keeps (a flood cannot grow it)


@dataclass(frozen=True, slots=True)
class SafetyParams:
    """Safety bounds; every field is a safety decision, validated at start-up."""

    # An input not received for this long (ms, local monotonic clock) forces a safe stop; in
    # (0, 10000]. Every input the gate watches is published several times faster than this.
    stale_ms: float = 250.0
    # A sender's clock further than this (ms, in wall time) from the rig clock is a clock fault,
    # not a fresh input; in (0, 60000]. Hosts are synchronised (NTP/PTP) well within it.
    skew_ms: float = 100.0
    # Services whose liveliness the device needs; never empty (it would turn the gate off).
    require_alive: tuple[str, ...] = ("decision", "vision")

    def __post_init__(self) -> None:
        for name, top in (("stale_ms", MAX_STALE_MS), ("skew_ms", MAX_SKEW_MS)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"safety.{name} must be a number, got {value!r}")
            if not (math.isfinite(value) and 0 < value <= top):
                raise ValueError(f"safety.{name} must be in (0, {top:.0f}] ms, got {value!r}")
        if not self.require_alive or not all(
            isinstance(s, str) and s for s in self.require_alive
        ):
            raise ValueError(
                "safety.require_alive must name at least one service (an empty list would "
                f"disable the liveliness gate), got {self.require_alive!r}"
            )


@dataclass(frozen=True, slots=True)
class SafetyStatus:
    """Whether the device must be in its safe state, and every reason why."""

    safe_stop: bool
    reasons: tuple[str, ...] = ()  # why the device must stop (empty: it may run)
    warnings: tuple[str, ...] = ()  # faults that do not stop it (a recent clock fault)

    @property
    def reason(self) -> str:
        """All reasons, then the warnings, in one line."""
        return "; ".join((*self.reasons, *self.warnings))


@dataclass
class Watchdog:
    """Tracks the inputs a device depends on; `check` says whether it must stop."""

    params: SafetyParams
    inputs: tuple[str, ...]
    _arrived: dict[str, int] = field(default_factory=dict)
    _alive: dict[str, bool] = field(default_factory=dict)
    _required: set[str] = field(default_factory=set)  # required now beyond params.require_alive
    _skew: dict[str, tuple[int, float]] = field(default_factory=dict)  # input → (arrival, ms)
    # input → recent (arrival, offset) pairs: the sender's clock is judged from the best of them
    _offsets: dict[str, deque[tuple[int, float]]] = field(default_factory=dict)
    latch: Latch = field(default_factory=Latch)  # the e-stop latch
    # Whether the latch is the rig's (its file read and the peers asked): a device that does
    # not know yet stays stopped, whatever its inputs.
    latch_known: bool = False
    # Why the latch in memory is not the one on disk (its host's disk is full, the folder gone);
    # empty once saved. A stop reason, never a warning: a device whose latch is unsaved could
    # come back from a restart released, so it does not move until a save succeeds.
    latch_unsaved: str = ""
    # The id acknowledged while the last command obeyed is not yet saved (None: it is saved).
    # An engage stops the device at once, before its latch reaches the disk (a slow fsync must
    # not delay a stop), but is acknowledged only once saved: an acknowledged e-stop survives
    # a restart, and one that cannot be saved is never acknowledged.
    _unsaved_ack: str | None = None
    _before_command: tuple[Latch, str | None] = (Latch(), None)  # to undo an unsaved release
    fault: str | None = None  # the device driver's fault, while it has one
    clock_faults: int = 0  # messages refused for their timestamp

    def feed(self, name: str, arrival_ns: int, offset_ns: float | None = None) -> bool:
        """A message on input `name` arrived at `arrival_ns` (local monotonic).

        `offset_ns` is its source timestamp minus the rig clock's reading at arrival, in wall
        time. Returns whether it counted as fresh (False: a clock fault).
        """
        if name not in self.inputs:
            raise KeyError(f"unknown input {name!r}; watched inputs are {self.inputs}")
        if offset_ns is not None:
            clock = self._clock_offset(name, arrival_ns, offset_ns)
            if clock is not None:
                self.clock_faults += 1
                self._skew[name] = (arrival_ns, clock / 1e6)
                return False
        self._arrived[name] = max(arrival_ns, self._arrived.get(name, arrival_ns))
        return True

    def _clock_offset(self, name: str, arrival_ns: int, offset_ns: float) -> float | None:
        """The clock fault this message shows (its offset, or its sender's), or None if none."""
        skew = self.params.skew_ms * 1e6
        if not (-(skew + self.params.stale_ms * 1e6) <= offset_ns <= skew):
            return offset_ns  # ahead beyond the bound (NaN too), or older than any fresh input
        window = self._offsets.setdefault(name, deque(maxlen=CLOCK_WINDOW_MESSAGES))
        window.append((arrival_ns, offset_ns))
        while window and window[0][0] < arrival_ns - CLOCK_WINDOW_NS:
            window.popleft()
        sender = max(o for _, o in window)  # the least-delayed message of the window
        return sender if sender < -skew else None

    def set_alive(self, service: str, alive: bool) -> None:
        """Record a liveliness change of a service."""
        self._alive[service] = alive

    def require(self, service: str, required: bool) -> None:
        """Require a service's liveliness from now on (or stop requiring it), e.g. in a trial."""
        if required:
            self._required.add(service)
        else:
            self._required.discard(service)

    def command(self, engaged: bool, reason: str, source: str, command_id: str) -> Verdict:
        """An e-stop command (engage or release): obeyed, a repeat, or refused (a stale release)."""
        self._before_command = (self.latch, self._unsaved_ack)
        self.latch, verdict = self.latch.command(engaged, reason, source, command_id)
        if verdict == "obeyed" and self._unsaved_ack is None:
            self._unsaved_ack = self._before_command[0].id
        return verdict

    def latch_saved(self) -> None:
        """The latch is on disk: acknowledge its last command."""
        self._unsaved_ack = None
        self.latch_unsaved = ""

    def latch_not_saved(self, why: str) -> None:
        """The latch could not be saved: no acknowledgement, and stopped until a save succeeds."""
        self.latch_unsaved = why or "not saved"

    def revert_command(self, why: str) -> None:
        """Undo the last command (a release) whose latch could not be saved: nothing changes.

        A release is obeyed only once it is on disk: otherwise a restart would bring back an
        e-stop the operator was told was lifted. Its id is not remembered, so `nod estop`
        repeating it retries the save.
        """
        self.latch, self._unsaved_ack = self._before_command
        self.latch_not_saved(why)

    def estop(self, engaged: bool, reason: str = "", command_id: str = "") -> Verdict:
        """Engage or release the e-stop (`command` without a source)."""
        return self.command(engaged, reason, "", command_id)

    def adopt(self, *holders: Latch) -> None:
        """The latch is known now: this device's, engaged if any other holder's is."""
        self.latch = merge(self.latch, holders)
        self.latch_known = True

    def set_fault(self, fault: str | None) -> None:
        """The device driver's fault (None: healthy)."""
        self.fault = fault or None

    @property
    def estopped(self) -> bool:
        """Whether the e-stop is engaged."""
        return self.latch.engaged

    @property
    def estop_id(self) -> str:
        """The last e-stop command obeyed (engage or release) and saved, for acknowledgements."""
        return self.latch.id if self._unsaved_ack is None else self._unsaved_ack

    def required(self) -> tuple[str, ...]:
        """Every service whose liveliness is needed now."""
        extra = sorted(s for s in self._required if s not in self.params.require_alive)
        return (*self.params.require_alive, *extra)

    def check(self, now_ns: int) -> SafetyStatus:
        """Every reason to be stopped now (none → may run); `now_ns` on the arrival clock."""
        reasons: list[str] = []
        warnings: list[str] = []
        if self.latch.engaged:
            reasons.append(f"e-stop: {self.latch.reason or 'engaged'}")
        if not self.latch_known:
            reasons.append("e-stop state not known yet")
        if self.fault is not None:
            reasons.append(f"device fault: {self.fault}")
        if self.latch_unsaved:
            reasons.append(f"e-stop latch not saved: {self.latch_unsaved}")
        for service in self.required():
            if not self._alive.get(service, False):
                reasons.append(f"{service} not alive")
        bound_ns = self.params.stale_ms * 1e6
        for name in self.inputs:
            last = self._arrived.get(name)
            skew = self._skew.get(name)
            if skew is not None and now_ns - skew[0] <= bound_ns:
                ahead = "ahead of" if skew[1] > 0 else "behind"
                warnings.append(f"{name} clock fault: stamped {abs(skew[1]):.0f} ms {ahead} ours")
            if last is None:
                reasons.append(f"no {name} yet")
            elif now_ns - last > bound_ns:
                reasons.append(f"{name} stale ({(now_ns - last) / 1e6:.0f} ms)")
        return SafetyStatus(bool(reasons), tuple(reasons), tuple(warnings))
