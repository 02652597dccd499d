"""What goes into the LSL streams: one row of the model's signals per hand pose, and markers.

**Signals** (`signal_names`): ẑ_h, z_r and b_r as the decision service computed them from one
hand pose (`decision/*`'s `src_seq` is the pose's `seq`), with that pose's hand centre (NaN when
no hand was seen or the pose itself was missed), stamped with the pose's `t_ns` (the decision
service stamps its values with it): when the camera frame was taken, the instant the three
values describe. A row goes out once all three values of its pose are in; a pose
whose values never all arrive (camera-rate keys drop under congestion) is left out, and only the
newest `PENDING` poses are waited for.

One key space, schema 3: every opinion message names its options. Over the paper's two options
a quantity is one channel, its signed value (`Opinions.signed`, z > 0 toward red), as it always
was (`SIGNALS`); over three or more it is one channel per option (`z_h:red`, `z_h:blue`, …).

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
from services.model.geometry import COLOURS

SCALARS = ("z_h", "z_r", "b_r")
HAND = ("hand_x", "hand_y")
SIGNALS = (*SCALARS, *HAND)  # the paper's two options: one signed channel per quantity
PENDING = 64  # poses waited for at once (two seconds at 30 Hz)


def signal_names(options: tuple[str, ...] = COLOURS) -> tuple[str, ...]:
    """The signal channels for an option set: `SIGNALS` over two, one per option over more."""
    if len(options) == 2:
        return SIGNALS
    return (*(f"{q}:{o}" for q in SCALARS for o in options), *HAND)


def _channels(msg: m.Opinions) -> tuple[float, ...]:
    """A quantity's channels: the signed value over two options, else every option's."""
    return (msg.signed,) if len(msg.values) == 2 else tuple(msg.values)


@dataclass(frozen=True, slots=True)
class Row:
    """One sample of the signals stream: its rig timestamp and the values of `SIGNALS`."""

    t_ns: int
    values: tuple[float, ...]


class SignalRows:
    """Joins each pose's ẑ_h, z_r and b_r (and the pose's centre) into one row.

    Its option set (`options`) fixes the row's channels (`signal_names`); a value over another
    set raises `MessageError` (the service then re-opens its outlet for that set: `restart`).
    """

    def __init__(self, options: tuple[str, ...] = COLOURS) -> None:
        self.options = tuple(options)
        self.names = signal_names(self.options)
        self._centres: OrderedDict[int, tuple[float, float] | None] = OrderedDict()
        self._values: OrderedDict[int, dict[str, tuple[int, tuple[float, ...]]]] = OrderedDict()

    def on_pose(self, pose: m.HandPose) -> None:
        """A hand pose: its centre, for the row its values will make."""
        self._centres[pose.seq] = pose.center if pose.detected else None
        _trim(self._centres)

    def on_value(self, name: str, msg: m.Opinions) -> Row | None:
        """One of ẑ_h, z_r, b_r; the pose's row once all three are in.

        MessageError (one line) if the message is over another option set than the rows'.
        """
        if name not in SCALARS:
            raise ValueError(f"{name!r} is not one of {SCALARS}")
        m.check_options(msg, self.options)
        got = self._values.setdefault(msg.src_seq, {})
        got[name] = (msg.t_ns, _channels(msg))
        _trim(self._values)
        if len(got) < len(SCALARS):
            return None
        del self._values[msg.src_seq]
        centre = self._centres.pop(msg.src_seq, None) or (math.nan, math.nan)
        return Row(got["z_r"][0], (*(v for s in SCALARS for v in got[s][1]), *centre))


def _trim(pending: OrderedDict[int, Any]) -> None:
    while len(pending) > PENDING:
        pending.popitem(last=False)


def marker(fields: dict[str, object]) -> str:
    """One marker's text: compact JSON, keys in the given order, empty values left out."""
    return json.dumps({k: v for k, v in fields.items() if v not in (None, "")},
                      ensure_ascii=False, separators=(",", ":"))


def _options(options: tuple[str, ...]) -> list[str] | None:
    """A marker's `options`: left out for the paper's red and blue (as before one key space)."""
    return None if tuple(options) == COLOURS else list(options)


def trial_marker(ev: m.TrialEvent) -> str:
    """A protocol event: setup (with mode, O and gaze level), a countdown word, go, end or why.

    O is an option's name; any other option set than the paper's is named in `options`.
    """
    fields: dict[str, object] = {"event": ev.phase, "trial": ev.trial, "session": ev.session,
                                 "options": _options(ev.options)}
    if ev.phase == "setup":
        fields |= {"mode": ev.mode, "option": ev.option, "gaze": ev.text}
    elif ev.phase in ("countdown", "go"):
        fields["word"] = ev.text
    else:  # end, interrupted, abort, session_end: why
        fields["why"] = ev.text
    return marker(fields)


def result_marker(res: m.TrialResult) -> str:
    """A trial's result: outcome, presses (by name) and score; `options` as for a trial event."""
    return marker({
        "event": "result", "trial": res.trial, "session": res.session, "outcome": res.outcome,
        "robot": res.robot, "human": res.human, "score": res.score,
        "interrupted": res.interrupted or None, "options": _options(res.options),
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
