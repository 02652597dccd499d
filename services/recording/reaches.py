"""Each trial's hand path from a recording: the poses of its last attempt, timed from its "go".

What the offline loop needs to run a recorded session instead of a simulated participant
(`run_offline_session(..., hands=recorded_hands(path))`): per trial, from its last "setup" to
its "end", every detected `vision/hand` pose as (seconds after that attempt's "go", landmarks),
on the poses' own stamps — the clock the live services judged them by.
"""

from __future__ import annotations

from pathlib import Path

from services.core.keys import topic_of
from services.model.replayed_hand import Pose
from services.recording.mcap_io import McapIn
from services.recording.selection import decode_entry


def recorded_hands(path: Path) -> dict[int, list[Pose]]:
    """The recording's trials (index → poses); a trial without a "go" is left out."""
    trials: dict[int, list[tuple[int, tuple[tuple[float, float], ...]]]] = {}
    go_ns: dict[int, int] = {}
    current: int | None = None
    for e in McapIn(path):
        topic = topic_of(e.key)
        if topic not in ("experiment/trial", "vision/hand") or not e.valid:
            continue
        msg = decode_entry(topic, e)
        if msg is None:
            continue
        if topic == "experiment/trial":
            if msg.phase == "setup":  # a new attempt: the earlier one's poses are void
                current = msg.trial
                trials[current] = []
                go_ns.pop(current, None)
            elif msg.phase == "go" and current is not None and msg.trial == current:
                go_ns[current] = msg.t_ns
            elif msg.phase in ("end", "interrupted", "abort", "session_end"):
                current = None
        elif current is not None and msg.detected and msg.landmarks:
            trials[current].append((msg.t_ns, tuple(msg.landmarks)))
    return {
        k: [((t - go_ns[k]) * 1e-9, pts) for t, pts in poses]
        for k, poses in sorted(trials.items())
        if k in go_ns and poses
    }
