"""`nod lab secure`: mutual TLS and an access-control list by host, end to end on loopback."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest
import zenoh

from services.core.keys import Keys
from services.core.session import make_config
from services.store import Store
from tests.processes import stop_all

from .conftest import ROOT, free_port, wait_for

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")
TWO_TRIALS = """
[[protocol.trials]]
index = 1
mode = "dissensus"
[[protocol.trials]]
index = 2
mode = "consensus"
option = "red"
gaze_level = "low"
"""


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

    def session(role: str) -> zenoh.Session:
        config = out / role / "zenoh.json5"
        for _ in range(100):
            try:
                return zenoh.open(make_config(mode="client", config_file=config))
            except zenoh.ZError:
                time.sleep(0.1)
        raise AssertionError(f"the {role} identity could not connect")

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
    stop_all(reversed(procs))


def test_without_a_certificate_nobody_connects(lab):
    port, session, _, _ = lab
    session("control").close()  # the router is up for those who have one
    for endpoint in (f"tcp/127.0.0.1:{port}", f"tls/127.0.0.1:{port}"):
        with pytest.raises(zenoh.ZError):
            zenoh.open(make_config(mode="client", connect=[endpoint])).close()


def test_the_camera_box_cannot_drive_the_arm_the_eyes_or_the_protocol(lab):
    _, session, _, _ = lab
    control, camera = session("control"), session("camera")
    try:
        got: list[str] = []
        alive: list[str] = []
        control.declare_subscriber(KEYS.all, lambda s: got.append(str(s.key_expr)))
        control.liveliness().declare_subscriber(
            f"nod/{KEYS.rig}/alive/**", lambda s: alive.append(str(s.key_expr)), history=True
        )
        time.sleep(0.5)
        forged = ["decision/z_r", "actuation/press", "eyes/cmd", "experiment/trial",
                  "safety/release"]
        for topic in forged:
            camera.put(KEYS.topic(topic), b"forged")
        token = camera.liveliness().declare_token(KEYS.alive("decision"))  # a fake decision
        camera.put(KEYS.topic("vision/hand"), b"allowed")  # its own key: must pass
        camera.put(KEYS.topic("safety/estop"), b"allowed")  # any host may engage the e-stop
        wait_for(lambda: KEYS.topic("safety/estop") in got, 5, "the camera's own messages")
        time.sleep(0.5)
        denied = [t for t in forged if KEYS.topic(t) in got]
        print(f"\nACL: {len(forged) - len(denied)} of {len(forged)} forged keys denied, the "
              "fake decision token denied")
        assert not denied, denied
        assert KEYS.topic("vision/hand") in got
        assert KEYS.alive("decision") not in alive
        token.undeclare()
    finally:
        camera.close()
        control.close()


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

    def estop(role: str, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-m", "services.cli", "estop", "--config",
             str(tmp / "lab" / role / "zenoh.json5"), *args],
            cwd=ROOT, capture_output=True, text=True, timeout=60,
        )

    engaged = estop("camera", "--reason", "from the camera box")
    assert engaged.returncode == 0, engaged.stdout + engaged.stderr  # any host may stop
    refused = estop("camera", "--release", "--timeout", "1")
    assert refused.returncode == 1 and "NOT by every device" in refused.stdout
    released = estop("control", "--release")  # exit 0: both devices acknowledged it
    assert released.returncode == 0, released.stdout + released.stderr
