"""One trial's samples, and the trial judge fed with the human's press and ẑ_h on the way.

Written once for any number of options: outputs come as `keyspace.Output` (at N options their
scalar columns stay NULL, `services.experiment.keyspace` says why) and the judge is the
session's (`TrialJudge`, `OptionsTrialJudge`). Decision outputs are joined to the hand pose
that produced them through `src_seq`, so the stored samples line up exactly even when messages
arrive interleaved.

A trial keeps at most `MAX_ROWS` poses, whatever a publisher floods the hand key with: the rest
are counted (`dropped`, one log line) and `drop_records` puts the count in the trial's events.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from services.model.judge import Judge
from services.store.records import RigEventRecord, Sample, pack_landmarks

if TYPE_CHECKING:  # the recorder reads decoded messages; it needs no codec
    from services.core import messages as m
    from services.experiment.keyspace import Output

log = logging.getLogger(__name__)
# Poses kept per trial: the longest trial the protocol's bounds allow (a 120 s timeout and a
# 60 s robot wait) at a 160 Hz camera. A 10 kHz flood of hand poses stops here (≈ 15 MB)
# instead of growing the conductor by ~0.5 kB a pose until the trial ends.
MAX_ROWS = 30_000


@dataclass(slots=True)
class _Row:
    t_ns: int
    detected: bool
    hand: tuple[float, float] | None
    values: dict[str, float | None] = field(default_factory=dict)
    ee: tuple[float, float] | None = None
    landmarks: bytes | None = None


class TrialSamples:
    """Collects what happens between "go" and the end of one trial."""

    def __init__(self, t_go_ns: int, judge: Judge[Any, Any, Any]) -> None:
        self.t_go_ns = t_go_ns
        self.judge = judge  # its clock: the poses' and outputs' t_ns
        self._rows: dict[int, _Row] = {}
        self._ee: tuple[float, float] | None = None
        self.dropped = 0  # poses not kept: the trial had MAX_ROWS

    @property
    def human(self) -> Any:
        """The human's press so far (the judge's)."""
        return self.judge.human

    def on_hand(self, pose: m.HandPose) -> None:
        """Record a pose; the judge looks for the human's press in it (on the trial's layout)."""
        if pose.t_ns < self.t_go_ns:
            return
        row = self._rows.get(pose.seq)
        if row is None and self._room():
            row = self._rows[pose.seq] = _Row(pose.t_ns, pose.detected, pose.center, ee=self._ee)
        if row is not None and pose.detected and row.landmarks is None:
            row.landmarks = pack_landmarks(pose.landmarks)
        if pose.detected:  # a full trial still sees the press
            self.judge.see_hand(pose.landmarks, pose.t_ns)

    def on_output(self, name: str, out: Output, pose: m.HandPose | None) -> None:
        """A decision output for hand pose `out.src_seq`; ẑ_h feeds the outcome until the press."""
        if out.t_ns < self.t_go_ns:
            return
        row = self._rows.get(out.src_seq)
        if row is None:
            if pose is None:
                return  # its pose was never seen (dropped): nothing to join it with
            if len(self._rows) >= MAX_ROWS:
                return  # full: its pose, if it came here, was counted
            row = self._rows[out.src_seq] = _Row(pose.t_ns, pose.detected, pose.center)
            if pose.detected:
                row.landmarks = pack_landmarks(pose.landmarks)
        row.values[name] = out.value
        if name == "z_h":
            row.values["theta"] = out.theta
            row.values["distance"] = out.distance
            self.judge.observe(out.z, row.hand, out.t_ns)

    def on_arm(self, ee: tuple[float, float]) -> None:
        """The latest end-effector position, attached to the following samples."""
        self._ee = ee

    def _room(self) -> bool:
        """Whether one more row fits; if not, count it (and say so once)."""
        if len(self._rows) < MAX_ROWS:
            return True
        self.dropped += 1
        if self.dropped == 1:
            log.warning("trial samples full (%d poses): further poses are counted, not kept",
                        MAX_ROWS)
        return False

    def drop_records(self, trial: int, attempt: int, t_ns: int) -> list[RigEventRecord]:
        """The count of what was not kept, for the trial's events (none if nothing was)."""
        if not self.dropped:
            return []
        text = f"{self.dropped} poses not recorded (at most {MAX_ROWS} per trial)"
        return [RigEventRecord(trial, attempt, t_ns, "", "experiment", "dropped", self.dropped,
                               text)]

    def decimated(self, max_hz: float) -> list[Sample]:
        """The recorded rows in time order, decimated to at most `max_hz`."""
        out: list[Sample] = []
        min_gap = int(1e9 / max_hz) if max_hz > 0 else 0
        last = None
        for seq in sorted(self._rows):
            r = self._rows[seq]
            if last is not None and r.t_ns - last < min_gap:
                continue
            last = r.t_ns
            hx, hy = r.hand if r.hand else (None, None)
            ex, ey = r.ee if r.ee else (None, None)
            out.append(
                Sample(
                    r.t_ns,
                    r.detected,
                    hx,
                    hy,
                    r.values.get("z_h"),
                    r.values.get("z_r"),
                    r.values.get("b_r"),
                    ex,
                    ey,
                    r.values.get("theta"),
                    r.values.get("distance"),
                    r.landmarks,
                )
            )
        return out
