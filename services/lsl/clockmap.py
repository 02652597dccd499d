"""The rig's clock on Lab Streaming Layer's: every rig timestamp as a `pylsl.local_clock()` time.

Every message carries `t_ns` on the rig clock (wall-clock ns, NTP/PTP-synchronised hosts; the
shared simulated clock under `--sim`). LSL stamps samples on its own clock, `local_clock()`
(seconds, the host's monotonic clock), and LabRecorder lines up streams from many machines by
measuring each outlet host's `local_clock()` against its own. So a rig event goes out stamped

    lsl_s = lsl_ref + (t_ns − rig_ref_ns) / 1e9 / speed

with (rig_ref_ns, lsl_ref) a pair of readings of both clocks taken at the same instant on this
host: the event's time on LSL's clock, not its arrival time (zenoh's delay, a few ms, does not
enter). The pair is read `PROBES` times, bracketing the rig reading by two LSL readings, and the
tightest bracket is kept (a read that was preempted is wider); its uncertainty is half that
width, typically under 2 µs. The pair is re-read every `REFRESH_S`: the wall clock is slewed by
NTP and LSL's is not, so the offset between them drifts (by ppm), and a stepped wall clock (NTP
correcting a large error) shows as a jump of the offset, logged with its size. LSL's own
`time_correction` (outlet host vs recorder host) then does the rest, as for any LSL device.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

PROBES = 5  # readings per refresh; the tightest is kept
REFRESH_S = 1.0
STEP_S = 0.001  # an offset change larger than this between refreshes is reported


@dataclass(frozen=True, slots=True)
class Anchor:
    """One instant read on both clocks: rig ns and LSL seconds, and how sure that is."""

    rig_ns: int
    lsl_s: float
    speed: float = 1.0  # rig-clock seconds per wall second (the simulated clock's)
    uncertainty_s: float = 0.0  # half the bracket of LSL readings around the rig reading

    def to_lsl(self, t_ns: int) -> float:
        """A rig timestamp on LSL's clock."""
        return self.lsl_s + (t_ns - self.rig_ns) / 1e9 / self.speed

    def to_rig_ns(self, lsl_s: float) -> int:
        """An LSL timestamp on the rig clock (the inverse of `to_lsl`)."""
        return self.rig_ns + round((lsl_s - self.lsl_s) * 1e9 * self.speed)

    def offset_s(self) -> float:
        """LSL time minus rig time at the anchor, in wall seconds (what drifts and steps)."""
        return self.lsl_s - self.rig_ns / 1e9 / self.speed


def read_anchor(
    rig_now_ns: Callable[[], int], lsl_now_s: Callable[[], float], speed: float = 1.0,
    probes: int = PROBES,
) -> Anchor:
    """Read both clocks `probes` times, each rig reading between two LSL readings; the tightest."""
    best: Anchor | None = None
    for _ in range(max(1, probes)):
        before = lsl_now_s()
        rig = rig_now_ns()
        after = lsl_now_s()
        half = (after - before) / 2
        if best is None or half < best.uncertainty_s:
            best = Anchor(rig, before + half, speed, half)
    assert best is not None
    return best
