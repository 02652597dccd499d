"""The operator's start gate and pause, as the conductor applies them.

With `[protocol] gate = true` each trial waits, after the rest, until the operator starts it:
`nod experiment next` publishes a start on `experiment/operator` (`services.tools.
operator`). Without the gate trials follow each other, and `nod experiment pause` holds the
next one until a start. A start counts only while a trial waits and the rig is safe ("ready →
start"); it names the trial it starts (0: whichever waits), so a late or repeated start never
starts the trial after, and a start while no trial waits is dropped.
"""

from __future__ import annotations

from services.core import messages as m
from services.model.protocol import Cue, SessionProtocol

NEXT_HINT = "nod experiment next"


class OperatorGate:
    """The operator's commands, taken on the fabric's thread, applied on the session's."""

    def __init__(self) -> None:
        self._start: int | None = None  # the trial a pending start names (0: the one waiting)
        self._pause = False
        self._announced: tuple[int, int] | None = None  # (trial, attempt) announced as waiting

    def command(self, msg: m.OperatorCmd) -> None:
        """A command from `nod experiment next|pause`."""
        if msg.action == "start":
            self._start = msg.trial
        else:
            self._pause = True

    def step(self, protocol: SessionProtocol, ready: bool, t: float) -> tuple[list[Cue], str]:
        """Apply what is pending: (the cues of a trial it started, a line for the operator)."""
        note = ""
        if self._pause:
            self._pause = False
            protocol.hold()
            note = f"paused: the next trial waits for `{NEXT_HINT}`"
        spec = protocol.trial
        if not protocol.waiting_for_operator or spec is None:
            self._start = None  # a start while no trial waits is for nothing: it never carries on
            return [], note
        start = self._start
        if start is not None and start not in (0, spec.index):
            self._start = None  # a start for another trial: stale
            start = None
        if start is not None and ready:
            self._start = None
            self._announced = None
            return protocol.open_gate(t), f"trial {spec.index} started by the operator"
        waiting = (spec.index, protocol.attempt)
        if self._announced != waiting:
            self._announced = waiting
            attempt = f" (attempt {protocol.attempt})" if protocol.attempt > 1 else ""
            note = (f"trial {spec.index}{attempt} ready: waiting for the operator — "
                    f"`{NEXT_HINT}` starts it")
        return [], note
