"""The operator's view of a running session, in the terminal that runs `nod experiment`.

The conductor tells the console what happens (`cue`, `value`, `robot`, `result`, `note`); the
console shows it:

- `LiveConsole` (a terminal): a panel redrawn 4 times a second with rich — the trial, its mode
  and option O, the countdown, live z_r / ẑ_h / b_r, where the robot is heading and where the
  person is heading, the finished trials with outcome and score, and the latest safety events
  and warnings (the conductor's log lines are routed into the panel instead of tearing it).
  The counter-click prompt is a line of the panel: the keys the operator types are drawn there
  (Enter ends the answer), so nothing else writes to the terminal while the panel runs.
- `LineConsole` (a pipe, a log file): one plain line per protocol step, result and event.
- `SessionConsole` itself shows nothing (`--console off`, and the tests).

The hooks are called with the conductor's lock held: they only store values; drawing happens
on rich's refresh thread (or inline for lines).
"""

from __future__ import annotations

import codecs
import contextlib
import logging
import os
import select
import sys
import threading
from collections import deque
from typing import Any

PHASES = {"setup": "gaze set", "countdown": "countdown", "go": "GO", "end": "judging",
          "interrupted": "INTERRUPTED"}
POLL_S = 0.1  # how often a prompt waiting for the operator looks whether the process must stop


class SessionConsole:
    """The hooks, showing nothing."""

    # Set when the process is asked to stop (the conductor's node.stop: SIGINT, SIGTERM): a
    # prompt waiting for the operator then gives up with KeyboardInterrupt within POLL_S.
    interrupt: threading.Event | None = None

    def start(self, session: str, participant: str, n_trials: int) -> None:
        """The session begins."""

    def cue(self, kind: str, trial: int, mode: str, option: str | None, text: str = "") -> None:
        """A protocol step: setup, countdown, go, end, interrupted."""

    def value(self, name: str, value: float) -> None:
        """A live value: z_h, z_r or b_r."""

    def robot(self, phase: str, target: str | None) -> None:
        """The arm's phase and the buzzer it is heading for."""

    def result(self, trial: int, mode: str, option: str | None, robot: str | None,
               human: str | None, outcome: str | None, score: int, interrupted: bool) -> None:
        """A stored trial."""

    def note(self, text: str, level: str = "info") -> None:
        """A safety event or a warning."""

    @property
    def interactive(self) -> bool:
        """Whether an operator types at this console (a terminal on standard input)."""
        fd = _stdin_fd()
        return type(self) is not SessionConsole and fd is not None and os.isatty(fd)

    def read_line(self, question: str, cancel: threading.Event | None = None) -> str:
        """Ask the operator for one line on the terminal (EOFError: input has ended).

        KeyboardInterrupt once the process must stop or `cancel` is set (the question is moot:
        a trial the operator was asked to start was started with `nod experiment next`). Keys
        typed on a terminal before the question are dropped: an Enter typed ahead must not
        answer a question not yet asked.
        """
        fd = _stdin_fd()
        if fd is None:
            return input(question)
        _drop_typed_ahead(fd)
        sys.stdout.write(question)
        sys.stdout.flush()
        return _read_line(fd, _AnyOf(self.interrupt, cancel))

    def stop(self) -> None:
        """The session is over."""


class LineConsole(SessionConsole):
    """One line per step, result and event: for a pipe or a log file."""

    def __init__(self, stream: Any = None) -> None:
        self.out = stream or sys.stdout
        self.n = 0

    def _line(self, text: str) -> None:
        self.out.write(text + "\n")
        self.out.flush()

    def start(self, session: str, participant: str, n_trials: int) -> None:
        """The session begins."""
        self.n = n_trials
        self._line(f"session {session} · participant {participant} · {n_trials} trials")

    def cue(self, kind: str, trial: int, mode: str, option: str | None, text: str = "") -> None:
        """A protocol step, on its own line (the countdown's numbers too)."""
        o = f" O={option}" if option else ""
        extra = f" {text}" if text else ""
        self._line(f"trial {trial}/{self.n} [{mode}{o}] {PHASES.get(kind, kind)}{extra}")

    def result(self, trial: int, mode: str, option: str | None, robot: str | None,
               human: str | None, outcome: str | None, score: int, interrupted: bool) -> None:
        """The stored trial."""
        what = "interrupted (not scored)" if interrupted else f"outcome {outcome or '-'}"
        self._line(f"trial {trial}: robot {robot or '-'}, human {human or '-'} → {what}, "
                   f"score {score}")

    def note(self, text: str, level: str = "info") -> None:
        """An event."""
        self._line(f"{level.upper()}: {text}")


class LiveConsole(SessionConsole):
    """The rich panel (see the module doc)."""

    def __init__(self) -> None:
        from rich.console import Console

        self.console = Console()
        self.lock = threading.Lock()
        self.session = self.participant = ""
        self.n = 0
        self.trial, self.mode, self.phase, self.text = 0, "", "waiting", ""
        self.option: str | None = None
        self.values: dict[str, float] = {}
        self.robot_phase = "idle"
        self.robot_target: str | None = None
        self.results: list[tuple] = []
        self.events: deque[tuple[str, str]] = deque(maxlen=6)
        self.question: str | None = None  # the prompt open in the panel, and what is typed
        self.typed = ""
        self._live: Any = None
        self._handler = _ConsoleLogHandler(self)
        self._saved_handlers: list[logging.Handler] = []

    # -- hooks -------------------------------------------------------------------------------

    def start(self, session: str, participant: str, n_trials: int) -> None:
        """Take over the terminal: the panel, and the log lines into it."""
        from rich.live import Live

        with self.lock:
            self.session, self.participant, self.n = session, participant, n_trials
        root = logging.getLogger()
        self._saved_handlers = list(root.handlers)
        for h in self._saved_handlers:
            root.removeHandler(h)
        root.addHandler(self._handler)
        self._live = Live(get_renderable=self.render, console=self.console,
                          refresh_per_second=4, transient=False)
        self._live.start()

    def cue(self, kind: str, trial: int, mode: str, option: str | None, text: str = "") -> None:
        """A protocol step."""
        with self.lock:
            if kind == "setup":
                self.values.clear()
            self.trial, self.mode, self.option = trial, mode, option
            self.phase, self.text = PHASES.get(kind, kind), text
            if kind == "interrupted":
                self.events.append(("warning", f"trial {trial} interrupted: {text}"))

    def value(self, name: str, value: float) -> None:
        """A live value."""
        with self.lock:
            self.values[name] = value

    def robot(self, phase: str, target: str | None) -> None:
        """The arm."""
        with self.lock:
            self.robot_phase, self.robot_target = phase, target

    def result(self, trial: int, mode: str, option: str | None, robot: str | None,
               human: str | None, outcome: str | None, score: int, interrupted: bool) -> None:
        """A stored trial."""
        with self.lock:
            self.results.append((trial, mode, option, robot, human, outcome, score, interrupted))

    def note(self, text: str, level: str = "info") -> None:
        """An event for the panel."""
        with self.lock:
            self.events.append((level, text))

    def read_line(self, question: str, cancel: threading.Event | None = None) -> str:
        """The operator's answer, typed into the panel's prompt line.

        On a terminal the keys are read one by one (no echo; Backspace and Ctrl-U edit, Enter
        ends, Ctrl-D on an empty line is the end of input, Ctrl-C still interrupts) and drawn
        by the panel itself. Answers from a pipe are read as lines while the panel asks.
        """
        fd = _stdin_fd()
        live = self._live
        if live is None or fd is None:  # no panel, or no input of ours to read keys from
            return super().read_line(question, cancel)
        _drop_typed_ahead(fd)
        with self.lock:
            self.question, self.typed = question, ""
        live.refresh()
        stop = _AnyOf(self.interrupt, cancel)
        try:
            return self._type(fd, stop) if os.isatty(fd) else _read_line(fd, stop)
        finally:
            with self.lock:
                self.question = None
            live.refresh()

    def _type(self, fd: int, stop: _AnyOf) -> str:
        """Keys from the terminal `fd` into `typed` (redrawn at each key) until Enter."""
        import termios
        import tty

        saved = termios.tcgetattr(fd)
        tty.setcbreak(fd, termios.TCSANOW)
        utf8 = codecs.getincrementaldecoder("utf-8")(errors="ignore")
        try:
            while True:
                key = _next_byte(fd, stop)
                if key == b"\x1b":  # an arrow or function key: not part of an answer
                    _skip_escape(fd)
                    continue
                ch = utf8.decode(key)
                if not key or ch in ("\r", "\n"):
                    return self.typed
                with self.lock:
                    if ch == "\x04" and not self.typed:
                        raise EOFError
                    if ch in ("\x7f", "\b"):
                        self.typed = self.typed[:-1]
                    elif ch == "\x15":
                        self.typed = ""
                    elif ch.isprintable():
                        self.typed += ch
                if self._live is not None:
                    self._live.refresh()
        finally:
            termios.tcsetattr(fd, termios.TCSADRAIN, saved)

    def stop(self) -> None:
        """Leave the last panel on screen and give the log back."""
        if self._live is not None:
            self._live.refresh()
            self._live.stop()
            self._live = None
        root = logging.getLogger()
        root.removeHandler(self._handler)
        for h in self._saved_handlers:
            root.addHandler(h)

    # -- drawing -----------------------------------------------------------------------------

    def render(self) -> Any:
        """The panel, from the values stored so far."""
        from rich.console import Group
        from rich.panel import Panel
        from rich.table import Table
        from rich.text import Text

        with self.lock:
            head = Text()
            head.append(f"trial {self.trial}/{self.n}  ", style="bold")
            head.append(self.mode or "-")
            if self.option:
                colour = "red" if self.option == "red" else "blue"
                head.append("  O = ")
                head.append(self.option, style=f"bold {colour}")
            head.append("   ")
            phase_style = "bold green" if self.phase == "GO" else (
                "bold red" if self.phase == "INTERRUPTED" else "bold")
            head.append(f"{self.phase} {self.text}".strip(), style=phase_style)
            asking = []
            if self.question is not None:
                line = Text(self.question, style="bold yellow")
                line.append(self.typed, style="bold")
                line.append("▌", style="blink")
                asking.append(line)
            live = Table.grid(padding=(0, 2))
            for name, label in (("z_r", "z_r"), ("z_h", "ẑ_h"), ("b_r", "b_r")):
                v = self.values.get(name)
                live.add_row(label, _bar(v) if v is not None else Text("–", style="dim"))
            zh = self.values.get("z_h", 0.0)
            human = "red" if zh > 0.5 else ("blue" if zh < -0.5 else "–")
            who = Text(f"robot: {self.robot_phase}"
                       + (f" → {self.robot_target}" if self.robot_target else ""))
            who.append(f"    human heading: {human}")
            done = Table("trial", "mode", "O", "robot", "human", "outcome", "score",
                         title="finished", title_justify="left", expand=False)
            total = sum(r[6] for r in self.results)
            for t, mode, o, rb, hu, oc, sc, intr in self.results[-8:]:
                done.add_row(str(t), mode, o or "-", rb or "-", hu or "-",
                             "interrupted" if intr else (oc or "-"), str(sc))
            events = [Text(t, style={"warning": "yellow", "error": "bold red"}.get(lv, "dim"))
                      for lv, t in self.events]
            title = f"session {self.session} · {self.participant} · score {total}"
            return Panel(Group(head, *asking, live, who, done, *events), title=title,
                         title_align="left")


def _bar(v: float, scale: float = 8.0, width: int = 21) -> Any:
    """A signed bar: blue to the left (< 0), red to the right (> 0)."""
    from rich.text import Text

    half = width // 2
    n = max(-half, min(half, round(v / scale * half)))
    left = " " * (half + min(n, 0)) + "█" * (-min(n, 0))
    right = "█" * max(n, 0) + " " * (half - max(n, 0))
    t = Text()
    t.append(left, style="blue")
    t.append("│")
    t.append(right, style="red")
    t.append(f" {v:+7.3f}")
    return t


class _ConsoleLogHandler(logging.Handler):
    """The conductor's warnings into the panel (an INFO line is not an event)."""

    def __init__(self, console: LiveConsole) -> None:
        super().__init__(logging.WARNING)
        self.target = console

    def emit(self, record: logging.LogRecord) -> None:
        level = "error" if record.levelno >= logging.ERROR else "warning"
        self.target.note(record.getMessage(), level)


def _stdin_fd() -> int | None:
    """The file descriptor of standard input, or None (closed, or replaced by a test runner)."""
    try:
        return sys.stdin.fileno()
    except (AttributeError, ValueError, OSError):  # io.UnsupportedOperation is both
        return None


class _AnyOf:
    """Set when any of some events is (None: never)."""

    def __init__(self, *events: threading.Event | None) -> None:
        self.events = [e for e in events if e is not None]

    def is_set(self) -> bool:
        return any(e.is_set() for e in self.events)


def _drop_typed_ahead(fd: int) -> None:
    """Drop the keys typed on a terminal before a question (a pipe's answers are kept)."""
    if os.isatty(fd):
        import termios

        with contextlib.suppress(termios.error):  # not ours to flush: keep them
            termios.tcflush(fd, termios.TCIFLUSH)


def _next_byte(fd: int, interrupt: _AnyOf | threading.Event | None) -> bytes:
    """The next byte from `fd` (b"" at its end); KeyboardInterrupt once `interrupt` is set."""
    while True:
        if interrupt is not None and interrupt.is_set():
            raise KeyboardInterrupt
        if select.select([fd], [], [], POLL_S)[0]:
            return os.read(fd, 1)


def _read_line(fd: int, interrupt: _AnyOf | threading.Event | None) -> str:
    """One line from `fd`, a byte at a time (nothing beyond it is taken from the stream)."""
    data = bytearray()
    while (byte := _next_byte(fd, interrupt)) != b"\n":
        if not byte:
            if not data:
                raise EOFError
            break
        data += byte
    return data.decode(errors="replace").rstrip("\r")


def _skip_escape(fd: int) -> None:
    """Drop the rest of an escape sequence (ESC [ A, ESC O P) that follows an ESC key."""
    if not select.select([fd], [], [], 0.05)[0]:
        return  # the Esc key alone
    kind = os.read(fd, 1)
    while kind in (b"[", b"O") and select.select([fd], [], [], 0.05)[0]:
        byte = os.read(fd, 1)
        if kind == b"O" or 0x40 <= byte[0] <= 0x7E:  # SS3 takes one byte; CSI ends on a final
            return


def make_console(kind: str) -> SessionConsole:
    """`auto` (a panel on a terminal, lines otherwise), `live`, `lines` or `off`."""
    if kind == "auto":
        kind = "live" if sys.stdout.isatty() else "lines"
    if kind == "live":
        return LiveConsole()
    if kind == "lines":
        return LineConsole()
    if kind == "off":
        return SessionConsole()
    raise ValueError(f"--console must be auto, live, lines or off, got {kind!r}")
