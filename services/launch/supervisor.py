"""Supervision of a rig's service processes: start, restart with backoff, give up, stop.

A `Supervisor` owns child processes (one per service). `poll()` — called from the launcher's
main thread a few times a second — notices a child that ended: a clean exit (code 0) is final;
an abnormal one (a non-zero code, a signal) is restarted after a backoff that doubles each time
(`RestartPolicy`), unless the service already restarted `max_restarts` times within `window_s`:
then it is reported as given up and left down (a crash loop is a fault to look at, not to hide).
Exit code 2 is every service's "bad input" (a wrong flag, a missing file or device): starting
it again cannot help, so it is given up at once. Every change is reported to `on_event` (the
launcher prints it and publishes it on rig/event), with the last line the service wrote to its
log — the cause, where the operator sees it.

Children must not outlive the launcher, even when it is killed with SIGKILL and can run no
cleanup: each child gets `NOD_PARENT_PID` and asks the kernel (prctl PR_SET_PDEATHSIG, see
`services.core.lifeline`) for a SIGTERM when its parent dies. Children are spawned from the
thread that calls `start`/`poll` (the kernel ties the signal to that thread), i.e. the main one.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

State = Literal["running", "waiting", "done", "failed", "stopped"]
EventKind = Literal["started", "exited", "restarting", "gave_up", "stopped"]


@dataclass(frozen=True)
class RestartPolicy:
    """When a service that died is started again."""

    backoff_initial_s: float = 0.25  # first restart after this; doubles each restart
    backoff_max_s: float = 5.0
    max_restarts: int = 5  # more restarts than this within `window_s`: give up
    window_s: float = 60.0

    def __post_init__(self) -> None:
        if not (0 <= self.backoff_initial_s <= self.backoff_max_s and self.window_s > 0):
            raise ValueError("restart backoff must be 0 <= initial <= max, window > 0")
        if self.max_restarts < 0:
            raise ValueError("max_restarts must be >= 0")

    def backoff(self, recent: int) -> float:
        """The wait before the restart that follows `recent` restarts within the window."""
        return min(self.backoff_max_s, self.backoff_initial_s * (2.0**recent))


@dataclass
class ServiceSpec:
    """One supervised service: how to start it and what its exit means."""

    name: str
    argv: Sequence[str]
    log: Path | None = None  # stdout and stderr go here (appended); None: inherit
    restart: bool = True  # restart after an abnormal exit
    env: dict[str, str] = field(default_factory=dict)
    # The command of a restart, when it differs (a conductor resumes its session); None from it
    # means there is nothing left to do (the conductor's session was complete when it died).
    restart_argv: Callable[[], Sequence[str] | None] | None = None


@dataclass
class Supervised:
    """A supervised service's run-time state."""

    spec: ServiceSpec
    proc: subprocess.Popen | None = None
    state: State = "waiting"
    restarts: int = 0
    last_code: int | None = None
    started_at: float = 0.0  # monotonic
    due_at: float = 0.0  # monotonic time of the next start while waiting
    recent: deque[float] = field(default_factory=deque)  # monotonic times of restarts


OnEvent = Callable[[str, EventKind, "int | None", int, str], None]


CONFIG_ERROR = 2  # every service's exit code for bad input: never restarted
TAIL_BYTES = 4096  # how much of a log's end is read for its last line


def last_line(log: Path | None) -> str:
    """The last non-empty line a service wrote to its log (clipped), or ""."""
    if log is None:
        return ""
    try:
        with log.open("rb") as fh:
            fh.seek(0, os.SEEK_END)
            fh.seek(max(0, fh.tell() - TAIL_BYTES))
            tail = fh.read().decode("utf-8", "replace")
    except OSError:
        return ""
    lines = [ln.strip() for ln in tail.splitlines() if ln.strip()]
    text = lines[-1] if lines else ""
    return text if len(text) <= 300 else text[:300] + "…"


def describe_exit(code: int) -> str:
    """How a child ended, in words: an exit code, or the signal that killed it."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exited with code {code}"


class Supervisor:
    """Start, watch, restart and stop a set of services (see the module doc)."""

    def __init__(
        self,
        policy: RestartPolicy | None = None,
        on_event: OnEvent | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.policy = policy or RestartPolicy()
        self.services: dict[str, Supervised] = {}
        self._on_event = on_event
        self._clock = clock
        self.stopping = False

    def _event(self, s: Supervised, kind: EventKind, code: int | None, text: str) -> None:
        if self._on_event is not None:
            self._on_event(s.spec.name, kind, code, s.restarts, text)

    def start(self, spec: ServiceSpec) -> Supervised:
        """Start a service now (replacing a finished one of the same name)."""
        old = self.services.get(spec.name)
        if old is not None and old.state == "running":
            raise ValueError(f"service {spec.name!r} is already running")
        s = Supervised(spec)
        self.services[spec.name] = s
        self._spawn(s, spec.argv)
        return s

    def _spawn(self, s: Supervised, argv: Sequence[str]) -> None:
        env = {
            **os.environ,
            **s.spec.env,
            "NOD_PARENT_PID": str(os.getpid()),
            "NOD_RESTARTS": str(s.restarts),
        }
        out = s.spec.log.open("a") if s.spec.log is not None else None
        try:
            s.proc = subprocess.Popen(
                list(argv),
                stdout=out,
                stderr=subprocess.STDOUT if out is not None else None,
                stdin=subprocess.DEVNULL,
                env=env,
                # Own session: the launcher's Ctrl-C is not theirs; it stops them in order.
                start_new_session=True,
            )
        finally:
            if out is not None:
                out.close()  # the child holds its own copy
        s.state = "running"
        s.started_at = self._clock()
        self._event(s, "started", None, f"pid {s.proc.pid}")

    def poll(self) -> None:
        """Notice exits, schedule and perform restarts (call a few times a second)."""
        now = self._clock()
        for s in list(self.services.values()):
            if s.state == "running" and s.proc is not None:
                code = s.proc.poll()
                if code is None:
                    continue
                s.last_code = code
                if code == 0 or self.stopping:
                    s.state = "done"
                    self._event(s, "exited", code, describe_exit(code))
                    continue
                while s.recent and now - s.recent[0] > self.policy.window_s:
                    s.recent.popleft()
                said = last_line(s.spec.log)
                cause = f" — {said}" if said else ""
                if code == CONFIG_ERROR:
                    s.state = "failed"
                    self._event(s, "gave_up", code, f"a configuration error (exit {code}): not "
                                f"restarted; fix it and start again{cause}")
                    continue
                if not s.spec.restart or len(s.recent) >= self.policy.max_restarts:
                    s.state = "failed"
                    why = (
                        f"{describe_exit(code)}; {len(s.recent)} restarts in the last "
                        f"{self.policy.window_s:g} s: not restarting"
                        if s.spec.restart
                        else f"{describe_exit(code)}; not restarted"
                    )
                    self._event(s, "gave_up", code, why + cause)
                    continue
                delay = self.policy.backoff(len(s.recent))
                s.state, s.due_at = "waiting", now + delay
                self._event(s, "restarting", code,
                            f"{describe_exit(code)}; again in {delay:.2f} s{cause}")
            elif s.state == "waiting" and now >= s.due_at and not self.stopping:
                argv = s.spec.restart_argv() if s.spec.restart_argv else s.spec.argv
                if argv is None:  # its work was done before it died: nothing to restart for
                    s.state = "done"
                    self._event(s, "exited", s.last_code, "its work was done: not restarted")
                    continue
                s.restarts += 1
                s.recent.append(now)
                self._spawn(s, argv)

    def state(self, name: str) -> State:
        """A service's state."""
        return self.services[name].state

    def failed(self) -> list[str]:
        """Services given up on."""
        return [n for n, s in self.services.items() if s.state == "failed"]

    def stop(self, names: Sequence[str] | None = None, grace_s: float = 5.0) -> None:
        """SIGTERM the services (all by default), SIGKILL what is left after `grace_s`."""
        chosen = [self.services[n] for n in (names or list(self.services)) if n in self.services]
        if names is None:
            self.stopping = True
        for s in chosen:
            if s.state == "waiting":
                s.state = "stopped"
            if s.state == "running" and s.proc is not None and s.proc.poll() is None:
                _signal_group(s.proc, signal.SIGTERM)
        deadline = self._clock() + grace_s
        for s in chosen:
            if s.proc is None or s.state not in ("running", "done"):
                continue
            try:
                s.proc.wait(max(0.0, deadline - self._clock()))
            except subprocess.TimeoutExpired:
                _signal_group(s.proc, signal.SIGKILL)
                s.proc.wait()
            if s.state == "running":
                s.state = "stopped"
                s.last_code = s.proc.returncode
                self._event(s, "stopped", s.proc.returncode, describe_exit(s.proc.returncode))


def _signal_group(proc: subprocess.Popen, sig: signal.Signals) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, sig)
