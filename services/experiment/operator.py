"""The operator's start gate and pause, as the conductor applies them.

With `[protocol] gate = true` each trial waits, after the rest, until the operator starts it:
`nod experiment next` publishes a start on `experiment/operator` (`services.tools.
operator`). Without the gate trials follow each other, and `nod experiment pause` holds the
next one until a start. A start counts only while a trial waits and the rig is safe ("ready →
start"); it names the trial it starts (0: whichever waits), so a late or repeated start never
starts the trial after, and a start while no trial waits is dropped.
"""

from __future__ import annotations

import threading
from typing import Protocol

from services.core import messages as m
from services.model.protocol import Cue, SessionProtocol

NEXT_HINT = "nod experiment next"


class OperatorGate:
    """The operator's commands, taken on the fabric's thread, applied on the session's."""

    def __init__(self) -> None:
        self._start: int | None = None  # the trial a pending start names (0: the one waiting)
        self._pause = False
        self._announced: tuple[int, int] | None = None  # (trial, attempt) announced as waiting
        self.starts_it = f"`{NEXT_HINT}`"  # what starts a waiting trial, as the operator reads it

    def command(self, msg: m.OperatorCmd) -> None:
        """A command from `nod experiment next|pause`."""
        if msg.action == "start":
            self._start = msg.trial
        else:
            self._pause = True

    def start(self, trial: int) -> None:
        """A start for `trial` from the operator's own console (Enter)."""
        self._start = trial

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
                    f"{self.starts_it} starts it")
        return [], note


class Asks(Protocol):
    """What `EnterStarts` needs of the console."""

    @property
    def interactive(self) -> bool:
        """Whether an operator types at it."""

    def read_line(self, question: str, cancel: threading.Event | None = None) -> str:
        """One line from the operator; KeyboardInterrupt once `cancel` is set."""


class EnterStarts:
    """Enter at the operator's terminal starts the trial waiting at the gate.

    Asked on a thread of its own while a trial waits (the session's loop goes on, and `nod
    experiment next` may start it first: the question is then withdrawn). Keys typed before the
    question are dropped by the console, so an Enter typed ahead starts nothing. Only on a
    terminal: a console fed from a pipe keeps its lines for the clicks prompt.
    """

    def __init__(self, console: Asks, gate: OperatorGate, lock: threading.RLock) -> None:
        self.console, self.gate, self.lock = console, gate, lock
        self._asking: tuple[int, threading.Event, threading.Thread] | None = None
        if console.interactive:
            gate.starts_it = f"Enter here or `{NEXT_HINT}`"

    def offer(self, trial: int) -> None:
        """A trial waits for the operator: ask (once) whether to start it."""
        if not self.console.interactive:
            return
        if self._asking is not None:
            if self._asking[0] == trial and self._asking[2].is_alive():
                return
            self.withdraw()
        cancel = threading.Event()
        thread = threading.Thread(target=self._ask, args=(trial, cancel), daemon=True,
                                  name="enter-starts")
        self._asking = (trial, cancel, thread)
        thread.start()

    def _ask(self, trial: int, cancel: threading.Event) -> None:
        try:
            self.console.read_line(
                f"trial {trial} ready — press Enter to start it (or `{NEXT_HINT}`) ", cancel
            )
        except (KeyboardInterrupt, EOFError):
            return  # started elsewhere, the session stopping, or no more input
        if not cancel.is_set():
            with self.lock:
                self.gate.start(trial)

    def withdraw(self) -> None:
        """The trial started (or the session ends): withdraw the question.

        It goes within the console's poll, before anything else reads the terminal.
        """
        if self._asking is not None:
            _, cancel, thread = self._asking
            cancel.set()
            thread.join(1.0)
            self._asking = None
