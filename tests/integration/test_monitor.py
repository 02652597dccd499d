"""`nod monitor --save`: a real monitor process on a real router records a synthetic stream."""

import signal
import socket
import time
import urllib.request

import cv2
import numpy as np
import pytest
from rerun.chunk import RrdReader

from services.core import messages as m
from services.core.keys import Keys
from services.monitor.bridge import rrd_rows

from .conftest import free_port, wait_for

pytestmark = pytest.mark.integration

N_POSES = 120  # one second of a 120 Hz camera
N_CAMERA = 30  # one second of the simulated 30 Hz camera


def _alive(session, keys: Keys, service: str) -> bool:
    replies = session.liveliness().get(keys.alive(service), timeout=0.5)
    return any(r.ok is not None for r in replies)


def _publish_session(client, keys: Keys) -> dict[str, int]:
    """A short synthetic stream like one trial's; returns how many of each were published."""
    pubs = {t: client.declare_publisher(keys.topic(t)) for t in keys_used()}
    seqs: dict[str, int] = dict.fromkeys(pubs, 0)
    t0 = time.time_ns()

    def put(topic: str, cls: type[m.Message], t_ns: int, **fields) -> None:
        pubs[topic].put(m.encode(cls(seq=seqs[topic], t_ns=t_ns, **fields)))
        seqs[topic] += 1

    paper = ("red", "blue")
    box = {"options": paper, "boxes": ((0.72, 0.12, 0.86, 0.26), (0.14, 0.12, 0.28, 0.26)),
           "commit_y": 0.45}
    put("vision/layout", m.Layout, t0, **box)
    put("experiment/trial", m.TrialEvent, t0, options=paper, phase="setup", trial=1,
        text="neutral")
    for k in (3, 2, 1):
        put("experiment/trial", m.TrialEvent, t0 + 1, options=paper, phase="countdown", trial=1,
            text=str(k))
    put("experiment/trial", m.TrialEvent, t0 + 2, options=paper, phase="go", trial=1)
    for i in range(N_POSES):
        t = t0 + 10_000_000 + i * 8_333_333
        x = 0.5 + 0.2 * i / N_POSES
        lm = ((x, 0.7), (x + 0.01, 0.71))
        put("vision/hand", m.HandPose, t, detected=True, center=(x + 0.005, 0.705), landmarks=lm)
        for topic, value in (("decision/z_h", x), ("decision/z_r", -x), ("decision/b_r", 0.1)):
            cls = m.Observed if topic == "decision/z_h" else m.Opinions
            put(topic, cls, t, src_seq=i, **m.signed_fields(value))
        if i % 10 == 0:
            put("actuation/state", m.ArmStateMsg, t, ee=(0.5, 0.1), phase="move", moving=True)
        time.sleep(1 / N_POSES)
    # `nod run --render`: the sim's 30 Hz camera (vision's input) and vision's 2 Hz frames
    for i in range(N_CAMERA):
        t = t0 + 10_000_000 + i * 33_333_333
        put("sim/camera", m.VisionFrame, t, jpeg=_jpeg(640, 480), width=640, height=480)
        if i % 15 == 0:
            put("vision/frame", m.VisionFrame, t, jpeg=_jpeg(320, 240), width=320, height=240)
    t_end = t0 + 2_000_000_000
    put("safety/estop", m.Estop, t_end, engaged=True, reason="test", source="pytest")
    put("experiment/trial", m.TrialEvent, t_end, options=paper, phase="end", trial=1)
    put("experiment/result", m.TrialResult, t_end, options=paper, trial=1, robot="red",
        human="red", outcome="C")
    return seqs


def _jpeg(width: int, height: int) -> bytes:
    return cv2.imencode(".jpg", np.full((height, width, 3), 90, np.uint8))[1].tobytes()


def keys_used() -> tuple[str, ...]:
    return (
        "sim/camera",
        "vision/frame",
        "vision/layout",
        "vision/hand",
        "decision/z_h",
        "decision/z_r",
        "decision/b_r",
        "actuation/state",
        "experiment/trial",
        "experiment/result",
        "safety/estop",
    )


def test_monitor_records_a_stream_and_closes_the_rrd_on_sigterm(client, spawn, tmp_path):
    keys = Keys("rig1")
    rrd = tmp_path / "session.rrd"
    proc = spawn("monitor", "--save", str(rrd))
    wait_for(lambda: _alive(client, keys, "monitor") or proc.poll() is not None, 15, "monitor")
    assert proc.poll() is None, proc.log_path.read_text()

    sent = _publish_session(client, keys)

    time.sleep(0.3)  # samples in flight on loopback; SIGTERM then drains the monitor's queue
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(15) == 0, proc.log_path.read_text()
    log = proc.log_path.read_text()
    assert "dropped none" in log, log

    rows, static = rrd_rows(rrd)
    assert rows["/table/hand"] == sent["vision/hand"] == N_POSES
    for topic in ("z_h", "z_r", "b_r"):
        assert rows[f"/opinion/{topic}"] == N_POSES
    assert rows["/table/arm"] == sent["actuation/state"] + 1  # + its colour, logged once
    assert rows["/state/trial"] == sent["experiment/trial"] == 6
    assert rows["/log/trial"] == 6
    assert rows["/log/result"] == 1
    assert rows["/log/safety"] == 1  # the estop
    assert static["/table/buzzers"] == 1 and static["/table/commit_line"] == 1
    # only vision's frames: the simulated camera is not recorded
    assert rows["/camera/frame"] == sent["vision/frame"] == 2 and sent["sim/camera"] == N_CAMERA
    reader = RrdReader(rrd)
    assert len(reader.blueprints()) == 1
    assert reader.store() is not None  # the footer was written: a clean close


def test_monitor_serving_the_web_viewer_prints_urls_that_open_it(client, spawn):
    keys = Keys("rig1")
    web, grpc = free_port(), free_port()
    proc = spawn("monitor", "--serve-web", "--web-port", str(web), "--grpc-port", str(grpc))
    wait_for(lambda: _alive(client, keys, "monitor") or proc.poll() is not None, 15, "monitor")
    assert proc.poll() is None, proc.log_path.read_text()
    lines = [ln for ln in proc.log_path.read_text().splitlines() if "web viewer" in ln]
    local = next(ln for ln in lines if "on this machine" in ln).split(": ", 2)[2].split(" ")[0]
    grpc_url = f"rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy"
    assert local == f"http://127.0.0.1:{web}/?url={grpc_url}"
    assert any(ln.startswith("nod monitor: web viewer: http://") for ln in lines)
    with urllib.request.urlopen(local, timeout=10) as page:  # the viewer's page is served
        assert page.status == 200 and b"<html" in page.read().lower()
    with socket.create_connection(("127.0.0.1", grpc), timeout=5):
        pass  # and the stream it connects to listens
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(15) == 0, proc.log_path.read_text()
