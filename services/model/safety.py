"""The safety gate of actuation and eyes: stale inputs, lost liveliness, e-stop → safe stop.

Pure and clock-free: the shell feeds it input timestamps, liveliness changes and e-stop messages
and asks `check(now_ns)`. An e-stop latches until an explicit release; staleness and lost
liveliness clear by themselves when fresh inputs (or the token) come back, because they describe
the present state of the inputs, not an operator's decision.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class SafetyParams:
    """Safety bounds; every field is a safety decision."""

    stale_ms: float = 250.0  # an input older than this (source time) forces a safe stop
    require_alive: tuple[str, ...] = ("decision", "vision")  # services whose loss stops us

    def __post_init__(self) -> None:
        if not self.stale_ms > 0:
            raise ValueError(f"stale_ms must be > 0, got {self.stale_ms}")


@dataclass(frozen=True, slots=True)
class SafetyStatus:
    """Whether the device must be in its safe state, and every reason why."""

    safe_stop: bool
    reasons: tuple[str, ...] = ()

    @property
    def reason(self) -> str:
        """All reasons in one line."""
        return "; ".join(self.reasons)


@dataclass
class Watchdog:
    """Tracks the inputs a device depends on; `check` says whether it must stop."""

    params: SafetyParams
    inputs: tuple[str, ...]
    _last_ns: dict[str, int] = field(default_factory=dict)
    _alive: dict[str, bool] = field(default_factory=dict)
    _estop: str | None = None

    def feed(self, name: str, t_ns: int) -> None:
        """Record a fresh message on input `name` with source time t_ns (monotone max)."""
        if name not in self.inputs:
            raise KeyError(f"unknown input {name!r}; watched inputs are {self.inputs}")
        self._last_ns[name] = max(t_ns, self._last_ns.get(name, t_ns))

    def set_alive(self, service: str, alive: bool) -> None:
        """Record a liveliness change of a service."""
        self._alive[service] = alive

    def estop(self, engaged: bool, reason: str = "") -> None:
        """Engage (latched) or release the e-stop."""
        self._estop = (reason or "e-stop") if engaged else None

    @property
    def estopped(self) -> bool:
        """Whether the e-stop is engaged."""
        return self._estop is not None

    def check(self, now_ns: int) -> SafetyStatus:
        """Every reason to be stopped now (none → may run)."""
        reasons: list[str] = []
        if self._estop is not None:
            reasons.append(f"e-stop: {self._estop}")
        for service in self.params.require_alive:
            if not self._alive.get(service, False):
                reasons.append(f"{service} not alive")
        bound_ns = self.params.stale_ms * 1e6
        for name in self.inputs:
            last = self._last_ns.get(name)
            if last is None:
                reasons.append(f"no {name} yet")
            elif now_ns - last > bound_ns:
                reasons.append(f"{name} stale ({(now_ns - last) / 1e6:.0f} ms)")
        return SafetyStatus(bool(reasons), tuple(reasons))
