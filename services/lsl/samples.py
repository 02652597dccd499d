"""What goes into the LSL streams: one row of the model's signals per hand pose, and markers.

**Signals** (`SIGNALS`): ẑ_h, z_r and b_r as the decision service computed them from one hand
pose (`decision/*`'s `src_seq` is the pose's `seq`), with that pose's hand centre (NaN when no
hand was seen or the pose itself was missed), stamped with the pose's `t_ns` (the decision
service stamps its values with it): when the camera frame was taken, the instant the three
values describe. A row goes out once all three values of its pose are in; a pose
whose values never all arrive (camera-rate keys drop under congestion) is left out, and only the
newest `PENDING` poses are waited for.

**Markers**: one JSON object per protocol event, result, e-stop and safe stop, e.g.
`{"event": "go", "trial": 4, "session": "…"}` — machine-readable in pyxdf or MNE, and readable
by eye in LabRecorder's viewer.
"""

from __future__ import annotations

import json
import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from services.core import messages as m

SIGNALS = ("z_h", "z_r", "b_r", "hand_x", "hand_y")
SCALARS = ("z_h", "z_r", "b_r")
PENDING = 64  # poses waited for at once (two seconds at 30 Hz)


@dataclass(frozen=True, slots=True)
class Row:
    """One sample of the signals stream: its rig timestamp and the values of `SIGNALS`."""

    t_ns: int
    values: tuple[float, ...]


class SignalRows:
    """Joins each pose's ẑ_h, z_r and b_r (and the pose's centre) into one row."""

    def __init__(self) -> None:
        self._centres: OrderedDict[int, tuple[float, float] | None] = OrderedDict()
        self._values: OrderedDict[int, dict[str, tuple[int, float]]] = OrderedDict()

    def on_pose(self, pose: m.HandPose) -> None:
        """A hand pose: its centre, for the row its values will make."""
        self._centres[pose.seq] = pose.center if pose.detected else None
        _trim(self._centres)

    def on_value(self, name: str, msg: m.Scalar) -> Row | None:
        """One of ẑ_h, z_r, b_r; the pose's row once all three are in."""
        if name not in SCALARS:
            raise ValueError(f"{name!r} is not one of {SCALARS}")
        got = self._values.setdefault(msg.src_seq, {})
        got[name] = (msg.t_ns, msg.value)
        _trim(self._values)
        if len(got) < len(SCALARS):
            return None
        del self._values[msg.src_seq]
        centre = self._centres.pop(msg.src_seq, None) or (math.nan, math.nan)
        return Row(got["z_r"][0], (*(got[s][1] for s in SCALARS), *centre))


def _trim(pending: OrderedDict[int, Any]) -> None:
    while len(pending) > PENDING:
        pending.popitem(last=False)


def marker(fields: dict[str, object]) -> str:
    """One marker's text: compact JSON, keys in the given order, empty values left out."""
    return json.dumps({k: v for k, v in fields.items() if v not in (None, "")},
                      ensure_ascii=False, separators=(",", ":"))


def trial_marker(ev: m.TrialEvent | m.OptionsTrialEvent) -> str:
    """A protocol event: setup (with mode, O and gaze level), a countdown word, go, end or why.

    On a table of N boxes O is a box index and the marker says `n_options`.
    """
    fields: dict[str, object] = {"event": ev.phase, "trial": ev.trial, "session": ev.session}
    if isinstance(ev, m.OptionsTrialEvent):
        fields["n_options"] = ev.n_options
    if ev.phase == "setup":
        fields |= {"mode": ev.mode, "option": ev.option, "gaze": ev.text}
    elif ev.phase in ("countdown", "go"):
        fields["word"] = ev.text
    else:  # end, interrupted, abort, session_end: why
        fields["why"] = ev.text
    return marker(fields)


def result_marker(res: m.TrialResult | m.OptionsResult) -> str:
    """A trial's result: outcome, presses and score (box indices and `n_options` for N boxes)."""
    return marker({
        "event": "result", "trial": res.trial, "session": res.session, "outcome": res.outcome,
        "robot": res.robot, "human": res.human, "score": res.score,
        "interrupted": res.interrupted or None,
        "n_options": res.n_options if isinstance(res, m.OptionsResult) else None,
    })


def estop_marker(cmd: m.Estop) -> str:
    """An e-stop engaged or released, with who and why."""
    return marker({"event": "estop" if cmd.engaged else "estop_release", "reason": cmd.reason,
                   "source": cmd.source, "id": cmd.id})


class SafeStops:
    """Turns a device's state stream into markers where its safe stop begins and ends."""

    def __init__(self) -> None:
        self._stopped: dict[str, bool] = {}

    def on_state(self, device: str, safe_stop: bool, reason: str) -> str | None:
        """A marker if this state changes whether `device` is in a safe stop."""
        before = self._stopped.get(device, False)
        self._stopped[device] = safe_stop
        if safe_stop == before:
            return None
        if safe_stop:
            return marker({"event": "safe_stop", "device": device, "reason": reason})
        return marker({"event": "safe_stop_cleared", "device": device})
