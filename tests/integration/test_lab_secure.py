"""`nod lab secure`: mutual TLS and an access-control list by identity, end to end on loopback.

Denials are observed, not assumed: each denied put or token is followed, on the same session, by
an allowed one; once the allowed one has arrived, a denied one that had passed would have too.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time

import pytest
import zenoh

from services.core import messages as m
from services.core.keys import Keys
from services.core.session import make_config
from services.lab.secure import main as secure_main
from services.store import Store
from tests.processes import stop_all
from tests.protocols import TWO_TRIALS

from .conftest import ROOT, free_port, wait_for

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")


@pytest.fixture
def lab(tmp_path):
    """A secured lab on loopback: identities, and the control station's router running."""
    port = free_port()
    out = tmp_path / "lab"
    made = subprocess.run(
        [sys.executable, "-m", "services.cli", "lab", "secure", "--out", str(out),
         "--router-host", "127.0.0.1", "--port", str(port)],
        cwd=ROOT, capture_output=True, text=True,
    )
    assert made.returncode == 0, made.stderr
    router = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "router", "--config",
         str(out / "control" / "router.json5")],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    procs: list[subprocess.Popen] = [router]
    sessions: list[zenoh.Session] = []

    def session(identity: str) -> zenoh.Session:
        """A session with one identity of the lab (a folder: `arm`, `arm/launcher`, `monitor`)."""
        config = out / identity / "zenoh.json5"
        deadline = time.monotonic() + 10
        while True:
            try:
                s = zenoh.open(make_config(mode="client", config_file=config))
                sessions.append(s)
                return s
            except zenoh.ZError:
                if time.monotonic() > deadline:
                    raise AssertionError(f"the {identity} identity could not connect") from None
                time.sleep(0.1)

    def start(role: str, *args: str) -> subprocess.Popen:
        log = (tmp_path / f"{args[0]}.log").open("a")
        proc = subprocess.Popen(
            [sys.executable, "-m", "services.cli", *args, "--config",
             str(out / role / "zenoh.json5")],
            cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
        )
        procs.append(proc)
        return proc

    yield port, session, start, tmp_path
    for s in sessions:
        s.close()
    stop_all(reversed(procs))


class Seen:
    """Every key a session receives (samples and liveliness tokens) on the rig."""

    def __init__(self, session: zenoh.Session) -> None:
        self.keys: list[str] = []
        self.alive: list[str] = []
        self.payloads: dict[str, bytes] = {}
        session.declare_subscriber(KEYS.all, self._on)
        session.liveliness().declare_subscriber(
            f"nod/{KEYS.rig}/alive/**", lambda s: self.alive.append(str(s.key_expr)),
            history=True,
        )

    def _on(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        self.keys.append(key)
        self.payloads[key] = sample.payload.to_bytes()

    def has(self, topic: str) -> bool:
        return KEYS.topic(topic) in self.keys


def put_until_seen(sender: zenoh.Session, seen: Seen, topic: str, what: str) -> None:
    """Put an allowed key until the subscriber has it (its subscription has propagated)."""
    deadline = time.monotonic() + 10
    while not seen.has(topic):
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        sender.put(KEYS.topic(topic), b"allowed")
        time.sleep(0.02)


def test_without_a_certificate_nobody_connects(lab):
    port, session, _, _ = lab
    session("control")  # the router is up for those who have one
    for endpoint in (f"tcp/127.0.0.1:{port}", f"tls/127.0.0.1:{port}"):
        with pytest.raises(zenoh.ZError):
            zenoh.open(make_config(mode="client", connect=[endpoint])).close()


def test_the_camera_box_cannot_drive_the_arm_the_eyes_or_the_protocol(lab):
    _, session, _, _ = lab
    seen = Seen(session("control"))
    camera = session("camera")
    put_until_seen(camera, seen, "vision/hand", "the camera's own key")  # its own key passes
    forged = ["decision/z_r", "actuation/press", "eyes/cmd", "experiment/trial",
              "safety/release", "rig/event"]
    for topic in forged:
        camera.put(KEYS.topic(topic), b"forged")
    token = camera.liveliness().declare_token(KEYS.alive("decision"))  # a fake decision
    own = camera.liveliness().declare_token(KEYS.alive("vision"))
    camera.put(KEYS.topic("safety/estop"), b"allowed")  # any host may engage the e-stop
    wait_for(lambda: seen.has("safety/estop"), 5, "the camera's e-stop")
    wait_for(lambda: KEYS.alive("vision") in seen.alive, 5, "the camera's own token")
    denied = [t for t in forged if seen.has(t)]
    print(f"\nACL: {len(forged) - len(denied)} of {len(forged)} forged keys denied, the "
          "fake decision token denied")
    assert not denied, denied
    assert KEYS.alive("decision") not in seen.alive
    token.undeclare()
    own.undeclare()


def test_only_a_launcher_identity_publishes_rig_events(lab):
    _, session, _, _ = lab
    seen = Seen(session("control"))
    arm, launcher = session("arm"), session("arm/launcher")
    put_until_seen(arm, seen, "decision/z_r", "the arm's own key")
    arm.put(KEYS.topic("rig/event"), b"forged by a service")  # a service of the arm host
    arm.put(KEYS.topic("rig/status"), b"allowed")  # its heartbeat passes
    wait_for(lambda: seen.has("rig/status"), 5, "the arm's heartbeat")
    assert not seen.has("rig/event"), "a service identity published a rig event"
    # The launcher: rig events pass; it cannot forge a service's key or engage the e-stop.
    launcher.put(KEYS.topic("decision/z_r"), b"forged by the launcher")
    launcher.put(KEYS.topic("safety/estop"), b"forged by the launcher")
    seen.payloads.clear()
    launcher.put(KEYS.topic("rig/event"), b"from the launcher")
    wait_for(lambda: KEYS.topic("rig/event") in seen.payloads, 5, "the launcher's rig event")
    assert seen.payloads[KEYS.topic("rig/event")] == b"from the launcher"
    assert KEYS.topic("decision/z_r") not in seen.payloads
    assert not seen.has("safety/estop")


def test_the_monitor_identity_reads_everything_and_drives_nothing(lab):
    _, session, _, _ = lab
    control, arm, camera, monitor = (session(n) for n in ("control", "arm", "camera", "monitor"))
    watch = Seen(monitor)  # the monitor's own view of the rig
    put_until_seen(arm, watch, "actuation/state", "actuation/state at the monitor")
    layout = camera.declare_queryable(
        KEYS.topic("vision/layout"), lambda q: q.reply(q.key_expr, b"layout")
    )
    replies: list[bytes] = []
    deadline = time.monotonic() + 10
    while not replies and time.monotonic() < deadline:  # the queryable propagates
        replies = [r.ok.payload.to_bytes() for r in monitor.get(KEYS.topic("vision/layout"),
                                                               timeout=0.5) if r.ok]
    assert replies == [b"layout"], "the monitor could not query the layout"
    seen = Seen(control)
    put_until_seen(arm, seen, "decision/z_r", "the control station's subscription")
    forged = ["safety/release", "safety/estop", "experiment/trial", "experiment/result",
              "rig/event", "actuation/cmd", "eyes/cmd", "vision/hand"]
    for topic in forged:
        monitor.put(KEYS.topic(topic), b"forged by a lab screen")
    fake = monitor.liveliness().declare_token(KEYS.alive("decision"))
    token = monitor.liveliness().declare_token(KEYS.alive("monitor"))
    monitor.put(KEYS.topic("rig/status"), b"allowed")  # its heartbeat, and nothing else
    wait_for(lambda: seen.has("rig/status"), 5, "the monitor's heartbeat")
    wait_for(lambda: KEYS.alive("monitor") in seen.alive, 5, "the monitor's token")

    def answered_alive() -> bool:  # one query's answers can miss the window on a loaded host
        alive = control.liveliness().get(f"nod/{KEYS.rig}/alive/**", timeout=1)
        return KEYS.alive("monitor") in [str(r.ok.key_expr) for r in alive if r.ok]

    wait_for(answered_alive, 15, "the monitor's token in a liveliness query")
    denied = [t for t in forged if seen.has(t)]
    print(f"\nmonitor identity: {len(forged) - len(denied)} of {len(forged)} keys denied "
          "(release, engage, trial, result, rig event, arm, gaze, hand), actuation/state and "
          "the layout query readable, only alive/monitor and rig/status passed")
    assert not denied, denied
    assert KEYS.alive("decision") not in seen.alive
    fake.undeclare()
    token.undeclare()
    layout.undeclare()


def test_only_the_devices_answer_the_latch_query(lab):
    """safety/latch is queried, never put: the arm and eyes answer it; no one else can."""
    _, session, _, _ = lab
    control, arm, camera = session("control"), session("arm"), session("camera")
    key = KEYS.topic("safety/latch")
    fake = camera.declare_queryable(key, lambda q: q.reply(q.key_expr, b"forged latch"))
    real = arm.declare_queryable(key, lambda q: q.reply(q.key_expr, b"arm latch"))
    replies: list[bytes] = []
    deadline = time.monotonic() + 10
    while b"arm latch" not in replies and time.monotonic() < deadline:
        replies = [r.ok.payload.to_bytes() for r in control.get(key, timeout=0.5) if r.ok]
    assert replies == [b"arm latch"], replies
    fake.undeclare()
    real.undeclare()


def test_the_router_listens_only_on_the_router_host(lab, tmp_path):
    port, session, _, _ = lab
    session("control")
    config = (tmp_path / "lab" / "control" / "router.json5").read_text()
    assert f'"tls/127.0.0.1:{port}"' in config and "0.0.0.0" not in config
    # Bound to 127.0.0.1 only: another loopback address of this host has nobody listening
    # (a tls/0.0.0.0 router would answer on every address of the control station).
    socket.create_connection(("127.0.0.1", port), timeout=2).close()
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.2", port), timeout=2).close()


def test_where_the_router_listens_follows_the_rig_file_or_says_why_not(tmp_path, capsys):
    port = free_port()
    rig = tmp_path / "rig.toml"
    rig.write_text(f'[rig]\nname = "lab3"\nrouter = "tls/127.0.0.5:{port}"\ntls = "tls"\n'
                   '[hosts.control]\nrouter = true\nservices = ["monitor"]\n')
    assert secure_main(["--out", str(tmp_path / "a"), "--rig-file", str(rig)]) == 0
    router = (tmp_path / "a" / "control" / "router.json5").read_text()
    client = (tmp_path / "a" / "arm" / "zenoh.json5").read_text()
    assert f'"tls/127.0.0.5:{port}"' in router and f'"tls/127.0.0.5:{port}"' in client
    assert '"nod/lab3/**"' in router
    capsys.readouterr()

    def refused(*args: str) -> str:
        assert secure_main(["--out", str(tmp_path / "b"), *args]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1
        return err

    assert "every interface" in refused("--router-host", "0.0.0.0")
    assert "tls/ endpoint" in refused("--listen", f"tcp/127.0.0.1:{port}")
    assert "not the port" in refused("--port", str(port), "--listen", "tls/127.0.0.1:1")
    assert "--rig-file gives" in refused("--rig-file", str(rig), "--port", "1")
    # A wildcard only when asked for, and then said out loud.
    assert secure_main(["--out", str(tmp_path / "c"), "--router-host", "127.0.0.1",
                        "--port", str(port), "--listen", f"tls/0.0.0.0:{port}"]) == 0
    assert "WARNING: the router listens on every interface" in capsys.readouterr().out


def test_nod_up_speaks_as_the_launcher_and_its_services_as_their_host(lab, tmp_path):
    port, session, _, _ = lab
    seen = Seen(session("control"))
    rig = tmp_path / "rig.toml"
    rig.write_text(
        f'[rig]\nrouter = "tls/127.0.0.1:{port}"\ntls = "{tmp_path / "lab"}"\n'
        '[hosts.control]\nrouter = true\nservices = []\n'
        '[hosts.arm]\nservices = ["decision"]\n'
    )
    up = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "up", str(rig), "--host", "arm", "--logs",
         str(tmp_path / "logs")],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    try:
        wait_for(lambda: seen.has("rig/event"), 30, "the arm launcher's rig event")
        event = m.decode(m.RigEvent, seen.payloads[KEYS.topic("rig/event")])
        assert event.service == "decision" and event.kind == "started"
        wait_for(lambda: KEYS.alive("decision") in seen.alive, 30, "decision, as the arm")
        wait_for(lambda: seen.has("rig/status"), 30, "decision's heartbeat")
    finally:
        up.send_signal(signal.SIGTERM)
        out, _ = up.communicate(timeout=20)
    assert up.returncode == 0, out
    assert "decision" in out and f"router at tls/127.0.0.1:{port}" in out


def test_a_session_runs_under_the_acl_and_only_the_control_station_releases(lab):
    _, session, start, tmp = lab
    params = tmp / "two.toml"
    params.write_text(TWO_TRIALS)
    clock = ["--speed", "4", "--epoch-ns", str(time.time_ns()), "--params", str(params)]
    start("arm", "decision", *clock)
    start("arm", "actuation", *clock)
    start("eyes", "eyes", *clock)
    start("camera", "sim", *clock)
    db = tmp / "s.sqlite"
    conductor = start("control", "experiment", *clock, "--db", str(db), "--clicks", "10")
    assert conductor.wait(120) == 0, (tmp / "experiment.log").read_text()[-3000:]
    store = Store(db)
    try:
        trials = [t for _, t in store.trials()]
    finally:
        store.close()
    assert [t.trial for t in trials] == [1, 2] and all(t.robot for t in trials)

    def estop(identity: str, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-m", "services.cli", "estop", "--config",
             str(tmp / "lab" / identity / "zenoh.json5"), *args],
            cwd=ROOT, capture_output=True, text=True, timeout=60,
        )

    engaged = estop("camera", "--reason", "from the camera box")
    assert engaged.returncode == 0, engaged.stdout + engaged.stderr  # any host may stop
    refused = estop("camera", "--release", "--timeout", "1")
    assert refused.returncode == 1 and "NOT by every device" in refused.stdout
    refused = estop("monitor", "--release", "--timeout", "1")  # a lab screen: never
    assert refused.returncode == 1 and "NOT by every device" in refused.stdout
    released = estop("control", "--release")  # exit 0: both devices acknowledged it
    assert released.returncode == 0, released.stdout + released.stderr
