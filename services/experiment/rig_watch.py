"""What the conductor knows of the rig's safety: each device's safe stop, the e-stop, their history.

Fed with the devices' state messages and the e-stop commands (the conductor's callbacks), it
keeps the safety events of the session (every change, with its reason) until they are stored,
says why a running trial must be interrupted, and whether the rig has been safe long enough to
resume. Events are stamped with the conductor's (rig) clock, passed in; how long a device has
been silent or the rig safe is judged on this host's monotonic clock, in wall time, like every
watchdog of the rig (a simulated clock at 4x must not make 125 ms of silence look like 500).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from services.core import messages as m
from services.model.intake import IntakeLimit
from services.store.records import RigEventRecord, SafetyEvent

DEVICES = ("actuation", "eyes")


@dataclass
class RigWatch:
    """The safety state of the rig's devices as their state keys report it."""

    settle_ns: int = 500_000_000  # how long the rig must stay safe before a session resumes
    silent_ns: int = 500_000_000  # a device whose state stops this long (a cut link) breaks a trial
    trial: int = 0
    attempt: int = 1
    monotonic: Callable[[], int] = time.monotonic_ns
    _stopped: dict[str, str] = field(default_factory=dict)  # device → reason, while stopped
    _seen: dict[str, int] = field(default_factory=dict)  # device → time of its last state
    _estop: str | None = None
    _safe_since: int | None = None
    _pending: list[SafetyEvent | RigEventRecord] = field(default_factory=list)
    _break: str | None = None  # the first new stop since the trial began
    # Other conductors' claims of this rig (services.core.claim) → when they appeared (monotonic).
    # One that gives way (it started later) is gone within its claim's grace: that holds the
    # next trial but does not void this one; one still there after `rival_grace_ns` does.
    _rivals: dict[str, int] = field(default_factory=dict)
    rival_grace_ns: int = 3_000_000_000
    # Launchers' events are kept, but not a flood of them (150,000 in 1.7 s once grew the
    # conductor by 106 MB and one trial's transaction by 198 MB): a burst of 50, then 2 a
    # second, at most 200 per trial attempt and 1000 per session (wall time, this host's clock).
    rig_events: IntakeLimit = field(
        default_factory=lambda: IntakeLimit(
            burst=50, per_s=2, per_scope=200, total=1000,
            scope_label="per trial attempt", total_label="per session",
        )
    )
    # Safety events too: a forged device state flipping `safe_stop` at 10 kHz must not grow the
    # conductor and the store without bound (the safety state itself follows every message; only
    # the records are limited): a burst of 100, then 10 a second, 500 per attempt, 5000 in all.
    safety_events: IntakeLimit = field(
        default_factory=lambda: IntakeLimit(
            burst=100, per_s=10, per_scope=500, total=5000,
            scope_label="per trial attempt", total_label="per session",
        )
    )
    # Per kind of event, the record counting those dropped in this attempt while it is still
    # pending: (the pending list it is in, its index there, the attempt).
    _dropped: dict[str, tuple[list[SafetyEvent | RigEventRecord], int, tuple[int, int]]] = (
        field(default_factory=dict)
    )

    def device_state(self, device: str, safe_stop: bool, reason: str, now_ns: int) -> None:
        """A device's state message: record each change of its safe stop."""
        self._seen[device] = self.monotonic()
        was = device in self._stopped
        if safe_stop and not was:
            self._stopped[device] = reason
            self._event(now_ns, device, "safe_stop", reason)
            self._break = self._break or f"{device}: {reason}"
        elif not safe_stop and was:
            del self._stopped[device]
            self._event(now_ns, device, "clear", "")
        self._update(now_ns)

    def estop(self, engaged: bool, reason: str, source: str, now_ns: int) -> None:
        """An e-stop command (engage or release) on the rig's key."""
        if engaged and self._estop is None:
            self._estop = reason or "e-stop"
            self._event(now_ns, "estop", "estop", f"{reason} ({source})")
            self._break = self._break or f"e-stop by {source}: {reason}"
        elif not engaged and self._estop is not None:
            self._estop = None
            self._event(now_ns, "estop", "release", f"{reason} ({source})")
        self._update(now_ns)

    def compromised(self, why: str, now_ns: int) -> None:
        """Something other than a device makes the trial untrustworthy (a second hand stream)."""
        self._break = self._break or why
        self._event(now_ns, "rig", "safe_stop", why)

    def rival(self, claim: str, present: bool, now_ns: int) -> None:
        """Another conductor's claim of this rig appeared (or went)."""
        if present and claim not in self._rivals:
            self._rivals[claim] = self.monotonic()
            self._event(now_ns, "experiment", "safe_stop", f"another conductor claims the rig "
                        f"(claim {claim})")
        elif not present and claim in self._rivals:
            del self._rivals[claim]
            self._event(now_ns, "experiment", "clear", f"the other conductor is gone ({claim})")
        self._update(now_ns)

    def begin(self, trial: int, attempt: int) -> None:
        """A trial (re)starts: later stops break it."""
        self.trial, self.attempt = trial, attempt
        self._break = None

    def lost(self, service: str, now_ns: int) -> None:
        """A service the session needs lost its liveliness."""
        self._event(now_ns, service, "safe_stop", "liveliness lost")
        self._break = self._break or f"{service} lost (liveliness)"

    def interruption(self, now_ns: int) -> str | None:
        """Why the running trial must stop (the first stop since it began), or None.

        A device that stopped reporting (its state key silent for `silent_ns`: a cut link, a
        hung host) breaks the trial too: its silence is no evidence that it is safe.
        """
        if self._break is None:
            mono = self.monotonic()
            for claim, since in self._rivals.items():
                if mono - since > self.rival_grace_ns:
                    self._break = f"another conductor on the rig (claim {claim})"
                    return self._break
            for device in DEVICES:
                seen = self._seen.get(device)
                if seen is not None and mono - seen > self.silent_ns:
                    why = f"{device}/state silent for {(mono - seen) / 1e6:.0f} ms"
                    self._event(now_ns, device, "safe_stop", why)
                    self._break = why
                    break
        return self._break

    def safe(self, now_ns: int) -> bool:
        """Whether every device reports no safe stop, no e-stop holds, for `settle_ns` now."""
        self._update(now_ns)
        mono = self.monotonic()
        fresh = all(mono - self._seen.get(d, -(2**62)) < self.settle_ns for d in DEVICES)
        return fresh and self._safe_since is not None and mono - self._safe_since >= self.settle_ns

    def heard_every_device(self) -> bool:
        """Whether a state of every device has arrived (since this conductor started)."""
        return all(d in self._seen for d in DEVICES)

    @property
    def estop_engaged(self) -> bool:
        """Whether an e-stop holds the rig (until a release)."""
        return self._estop is not None

    def why_unsafe(self) -> str:
        """What holds the rig, in one line."""
        parts = [f"{d}: {r}" for d, r in sorted(self._stopped.items())]
        parts += [f"another conductor claims this rig (claim {c})" for c in sorted(self._rivals)]
        if self._estop is not None:
            parts.insert(0, f"e-stop engaged ({self._estop})")
        missing = [d for d in DEVICES if d not in self._seen]
        parts += [f"no state from {d}" for d in missing]
        return "; ".join(parts) or "settling"

    def rig_event(self, now_ns: int, msg: m.RigEvent) -> None:
        """A launcher's event (a service restarted, given up…): kept with the session's events.

        Rate-limited and capped (`rig_events`). What is dropped is counted in one record per
        trial attempt and batch of stored events: kind "dropped", `code` how many, stamped at
        the first one dropped.
        """
        why = self.rig_events.admit(self.monotonic(), (self.trial, self.attempt))
        if why is not None:
            self._count_drop("rig events", self.rig_events, why, now_ns)
            return
        self._pending.append(
            RigEventRecord(
                self.trial, self.attempt, now_ns, msg.host, msg.service, msg.kind, msg.code,
                msg.text,
            )
        )

    def _count_drop(self, what: str, limit: IntakeLimit, why: str, now_ns: int) -> None:
        """One more `what` dropped: counted in one record per attempt and batch of events."""
        attempt = (self.trial, self.attempt)
        held = self._dropped.get(what)
        if held is not None and held[0] is self._pending and held[2] == attempt:
            index = held[1]
            old = self._pending[index]
            assert isinstance(old, RigEventRecord) and old.code is not None  # ours, below
            n, t0 = old.code + 1, old.t_ns
        else:
            index, n, t0 = len(self._pending), 1, now_ns
            self._pending.append(RigEventRecord(
                self.trial, self.attempt, t0, "", "experiment", "dropped", 0, ""
            ))
            self._dropped[what] = (self._pending, index, attempt)
        self._pending[index] = RigEventRecord(
            self.trial, self.attempt, t0, "", "experiment", "dropped", n,
            f"{n} {what} dropped ({why}; limits: {limit.describe()})",
        )

    def take_events(self) -> list[SafetyEvent | RigEventRecord]:
        """The events not stored yet (they go with the next trial, interruption or session end)."""
        out, self._pending = self._pending, []
        return out

    def _update(self, now_ns: int) -> None:
        unsafe = bool(self._stopped) or self._estop is not None or bool(self._rivals)
        if unsafe:
            self._safe_since = None
        elif self._safe_since is None:
            self._safe_since = self.monotonic()

    def _event(self, now_ns: int, device: str, event: str, reason: str) -> None:
        why = self.safety_events.admit(self.monotonic(), (self.trial, self.attempt))
        if why is not None:
            self._count_drop("safety events", self.safety_events, why, now_ns)
            return
        self._pending.append(
            SafetyEvent(self.trial, self.attempt, now_ns, device, event, reason[:400])
        )
