"""Fixtures for tests that start real processes on a real Zenoh router on a free loopback port."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator

import pytest

from services.core import messages as m
from services.core.keys import Keys
from services.core.session import make_config, open_session
from services.store import Store
from tests.polling import wait_for as wait_for  # the integration tests import it from here
from tests.processes import MARK_ENV, free_port, processes_marked, stop_all
from tests.protocols import SHORT as SHORT  # a three-trial protocol: whole sessions in seconds

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# SHORT on a table of three boxes: three trials, one control and two consensus, O by name (the
# one conductor runs it on the one key space; the tests of N = 2 are parametrised with it).
SHORT_THREE = """
[protocol]
options = ["red", "blue", "green"]
trials = [
    { index = 1, mode = "dissensus" },
    { index = 2, mode = "consensus", option = "green", gaze_level = "low" },
    { index = 3, mode = "consensus", option = "blue", gaze_level = "significant" },
]
"""
# SHORT with the devices' safety bounds relaxed (stale inputs 1 s, clock skew 0.5 s), for tests
# whose subject is something else (a bus fault, a kill -9, a resume) run at 2-4x: there a loaded
# host's late messages would otherwise break every attempt of a trial and end the session early.
# The bounds themselves are tested at 1x (test_safety.py) and by the tests that use SHORT.
RELAXED = SHORT + """
[safety]
stale_ms = 1000.0
skew_ms = 500.0
"""


@pytest.fixture(autouse=True)
def _no_process_outlives_its_test(request, monkeypatch):
    """Fail a test that leaves a process running after its teardown; end the process.

    Every process a test starts, and everything those start, inherits a mark of that test. A
    service that outlives its launcher (an orphan under init after a kill -9, a child whose
    SIGTERM path hangs) would otherwise run on into the next tests, holding a port, a serial
    device or a rig's keys. The grace covers a loaded machine's slow but clean shutdowns.
    """
    mark = f"{os.getpid()}-{time.monotonic_ns()}"
    monkeypatch.setenv(MARK_ENV, mark)
    yield
    left: dict[int, str] = {}

    def all_gone() -> bool:
        left.clear()
        left.update({pid: cmd for pid, cmd in processes_marked(mark).items() if pid != os.getpid()})
        return not left

    deadline = time.monotonic() + 20.0
    while not all_gone() and time.monotonic() < deadline:
        time.sleep(0.1)
    if left:
        for pid in left:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        pytest.fail(f"{request.node.name} left {len(left)} process(es) running 20 s after its "
                    "teardown (killed now): " + "; ".join(f"{p}: {c}" for p, c in left.items()))


@pytest.fixture
def endpoint() -> str:
    """A fresh loopback endpoint per test: two test runs never share a port."""
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def router(endpoint):
    """A Zenoh router session listening on the endpoint."""
    session = open_session(make_config(mode="router", listen=[endpoint]))
    yield session
    session.close()


@pytest.fixture
def client(router, endpoint):
    """A client session connected to the router."""
    session = open_session(make_config(mode="client", connect=[endpoint]))
    yield session
    session.close()


@pytest.fixture
def spawn(endpoint, tmp_path) -> Iterator[Callable[..., subprocess.Popen]]:
    """Start `nod <service> --connect <endpoint> …` as a child process; stopped at teardown."""
    procs: list[subprocess.Popen] = []

    def start(service: str, *args: str) -> subprocess.Popen:
        log = (tmp_path / f"{service}.log").open("w")
        proc = subprocess.Popen(
            [sys.executable, "-m", "services.cli", service, "--connect", endpoint, *args],
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            cwd=ROOT,
        )
        proc.log_path = tmp_path / f"{service}.log"  # type: ignore[attr-defined]
        procs.append(proc)
        return proc

    yield start
    stop_all(procs)


class Collector:
    """Decodes and keeps every sample of one key, with its arrival time."""

    def __init__(self, session, key: str, cls: type[m.Message]) -> None:
        self.items: list[tuple[float, m.Message]] = []
        self.bad = 0
        self._sub = session.declare_subscriber(key, self._on)
        self.cls = cls

    def _on(self, sample) -> None:
        try:
            self.items.append((time.monotonic(), m.decode(self.cls, sample.payload.to_bytes())))
        except m.MessageError:
            self.bad += 1

    @property
    def messages(self) -> list[m.Message]:
        return [msg for _, msg in self.items]


class FakeConductor:
    """Holds the conductor's liveliness and keeps the gaze alive (the eyes need both)."""

    def __init__(self, client) -> None:
        keys = Keys("rig1")
        self.token = client.liveliness().declare_token(keys.alive("experiment"))
        self.pub = client.declare_publisher(keys.topic("eyes/cmd"))
        self.quit = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        seq = 0
        while not self.quit.wait(0.05):
            seq += 1
            self.pub.put(m.encode(m.GazeMsg(seq=seq, t_ns=time.time_ns(), yaw=0.3, trial=1)))

    def close(self) -> None:
        self.quit.set()
        self.thread.join()
        self.token.undeclare()


def connect_when_listening(
    endpoint: str, timeout_s: float = 30.0, alive: Callable[[], bool] | None = None
):
    """A client session on a router that is starting up (`nod run`, `nod router`), once it
    listens; ConnectionError after `timeout_s`, or as soon as `alive()` says its process died."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return open_session(make_config(mode="client", connect=[endpoint]))
        except ConnectionError:
            if time.monotonic() > deadline or (alive is not None and not alive()):
                raise
            time.sleep(0.05)


def last_session_record(db, trials_of: Callable[[Store, str], list]) -> tuple[list, list, list]:
    """The trials (`trials_of(store, session)`), interruptions and safety events of the store's
    last session, read and the store closed again."""
    store = Store(db)
    try:
        session = store.sessions()[-1]["session"]
        return trials_of(store, session), store.interruptions(session), store.safety_events(session)
    finally:
        store.close()


def assert_estop_broke_trial_2_and_every_break_was_repeated(trials, broken, context: str) -> None:
    """A 3-trial session whose trial 2 an e-stop ("bump") broke once: every trial stored once,
    and every broken start repeated by the paper's rule (a loaded host's stale inputs may break an
    attempt too); a trial is stored interrupted only after its last attempt broke as well."""
    assert [t.trial for t in trials] == [1, 2, 3], context
    by_estop = [b for b in broken if "bump" in b.reason]
    assert [(b.trial, b.attempt) for b in by_estop] == [(2, 1)], context
    assert "e-stop" in by_estop[0].reason, context
    for t in trials:
        starts = [b for b in broken if b.trial == t.trial]
        assert t.attempts == len(starts) + (0 if t.interrupted else 1), context
        assert not t.interrupted or t.attempts == 3, context
    assert trials[1].attempts >= 2, context
