"""`nod vision` as a real process on a real router: hand poses, layout, monitor frames, errors."""

import math
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from services.core import messages as m
from services.core.keys import Keys
from services.core.session import make_config, open_session
from services.model.geometry import Box, CommitLine, OptionsLayout, TableLayout
from services.scene.render import HandPath, SceneRenderer, demo_path, write_video
from services.vision.calibration import dump_calibration

from .conftest import ROOT, Collector, wait_for

pytestmark = pytest.mark.integration

KEYS = Keys("rig1")
LAYOUT = TableLayout(
    red=Box(0.70, 0.10, 0.88, 0.28), blue=Box(0.12, 0.10, 0.30, 0.28), commit=CommitLine(0.5)
)


def _path_with_a_gap() -> HandPath:
    """Reach red, vanish for a while (the hand leaves the camera), come back, reach blue."""
    (rx, ry), (bx, by) = LAYOUT.red.center, LAYOUT.blue.center
    return HandPath(
        (
            (0.0, 0.5, 0.85),
            (1.0, rx, ry),
            (1.4, None, None),
            (1.8, 0.5, 0.85),
            (2.8, bx, by),
            (3.0, bx, by),
        )
    )


def _subscribe(client):
    return (
        Collector(client, KEYS.topic("vision/hand"), m.HandPose),
        Collector(client, KEYS.topic("vision/layout"), m.Layout),
        Collector(client, KEYS.topic("vision/frame"), m.VisionFrame),
    )


def test_vision_publishes_the_rendered_path_of_a_video_file(client, spawn, tmp_path):
    video, cal = tmp_path / "run.avi", tmp_path / "table.toml"
    truth = write_video(video, SceneRenderer(layout=LAYOUT, noise=2.0), _path_with_a_gap(), 15.0)
    cal.write_text(dump_calibration(LAYOUT))
    hands, layouts, frames = _subscribe(client)
    proc = spawn(
        "vision",
        *("--source", str(video), "--tracker", "aruco", "--calibration", str(cal)),
        *("--wait-for-subscriber", "10", "--frames-key-hz", "20"),
    )
    assert proc.wait(30) == 0, proc.log_path.read_text()
    wait_for(lambda: len(hands.items) >= len(truth), 5, "every hand pose")
    poses = hands.messages
    assert [p.seq for p in poses] == list(range(len(truth)))  # one pose per frame, in order
    assert hands.bad == layouts.bad == frames.bad == 0
    good = 0
    for pose, hand in zip(poses, truth, strict=True):
        assert pose.source == "aruco"
        if hand is None:
            assert not pose.detected and pose.center is None and pose.landmarks == ()
        elif pose.detected and math.dist(pose.center, hand[:2]) <= 0.01:
            good += 1
    assert good >= 0.95 * sum(h is not None for h in truth)
    assert all(b.t_ns >= a.t_ns for a, b in zip(poses, poses[1:], strict=False))
    lay = layouts.messages[0]
    assert (lay.options, lay.boxes, lay.commit_y) == (
        ("red", "blue"),
        ((0.7, 0.1, 0.88, 0.28), (0.12, 0.1, 0.3, 0.28)),
        0.5,
    )
    assert frames.items, "no monitor frame"
    shot = frames.messages[-1]
    img = cv2.imdecode(np.frombuffer(shot.jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (shot.height, shot.width, 3) == (240, 320, 3)
    assert 0 <= shot.hand_seq < len(truth)


THREE = OptionsLayout(
    (Box(0.12, 0.10, 0.30, 0.28), Box(0.41, 0.10, 0.59, 0.28), Box(0.70, 0.10, 0.88, 0.28)),
    CommitLine(0.5),
)


@pytest.mark.parametrize("n", [2, 3])
def test_late_joiners_get_the_layout_and_sigterm_stops_cleanly(
    client, endpoint, spawn, tmp_path, n
):
    """The table from the calibration file on vision/layout, the paper's two boxes or N."""
    cal = tmp_path / "table.toml"
    key, cls = "vision/layout", m.Layout
    if n == 2:
        cal.write_text(dump_calibration(LAYOUT))
        options: tuple[str, ...] = ()
    else:
        cal.write_text(dump_calibration(THREE, names=("red", "blue", "green")))
        options = ("--options", "3")
    hands = Collector(client, KEYS.topic("vision/hand"), m.HandPose)
    layouts = Collector(client, KEYS.topic(key), cls)
    proc = spawn(
        "vision",
        *("--source", "sim", "--tracker", "sim", "--realtime", "--loop", "--fps", "30"),
        *("--calibration", str(cal), "--frames-key-hz", "0", *options),
    )
    wait_for(lambda: sum(p.detected for p in hands.messages) >= 10, 20, "hand poses from sim")
    assert all(len(p.landmarks) == 21 for p in hands.messages if p.detected)
    assert {p.source for p in hands.messages} == {"sim"}
    wait_for(lambda: layouts.messages, 5, "the layout published")
    late = open_session(make_config(mode="client", connect=[endpoint]))
    try:
        replies = [r for r in late.get(KEYS.topic(key), timeout=3.0) if r.ok]
    finally:
        late.close()
    assert replies, "nobody answered a get on the layout key"
    for lay in (layouts.messages[0], m.decode(cls, replies[0].ok.payload.to_bytes())):
        if n == 2:
            assert lay.options == ("red", "blue")
            assert lay.boxes[0] == (0.7, 0.1, 0.88, 0.28) and lay.commit_y == 0.5
        else:
            assert lay.options == ("red", "blue", "green") and lay.table() == THREE
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(10) == 0, proc.log_path.read_text()


def test_a_truncated_file_ends_the_service_with_a_clear_error(router, endpoint, tmp_path):
    video = tmp_path / "full.avi"
    write_video(video, SceneRenderer(width=320, height=240), demo_path(), fps=10.0)
    cut = tmp_path / "cut.avi"
    data = video.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    proc = subprocess.run(
        [sys.executable, "-m", "services.vision", "--connect", endpoint, "--source", str(cut)],
        capture_output=True,
        text=True,
        timeout=30,
        cwd=ROOT,
    )
    assert proc.returncode == 1
    assert "is truncated or damaged: decoded" in proc.stderr
    assert "Traceback" not in proc.stderr


HAND_JPG = Path(ROOT) / "tests" / "fixtures" / "hand" / "hand_on_table.jpg"


def test_vision_with_mediapipe_tracks_a_real_hand_from_a_video_file(client, spawn, tmp_path):
    """`nod vision --tracker mediapipe` (no -v: the OpenCV log-level call runs) on a real hand."""
    pytest.importorskip(
        "mediapipe", reason="the mediapipe extra is not installed (scripts/setup-env --mediapipe)"
    )
    photo = cv2.imread(str(HAND_JPG))
    table = SceneRenderer(width=640, height=480, noise=2.0).render(None)
    shown = [True] * 6 + [False] * 4 + [True] * 6  # the hand, gone, back
    video = tmp_path / "hand.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (640, 480))
    for hand in shown:
        writer.write(photo if hand else table)
    writer.release()
    hands, _, frames = _subscribe(client)
    proc = spawn(
        "vision",
        *("--source", str(video), "--tracker", "mediapipe", "--model-complexity", "0"),
        *("--wait-for-subscriber", "10", "--frames-key-hz", "20"),
    )
    assert proc.wait(60) == 0, proc.log_path.read_text()
    log = proc.log_path.read_text()
    assert "Traceback" not in log and "AttributeError" not in log, log
    wait_for(lambda: len(hands.items) >= len(shown), 5, "every hand pose")
    poses = hands.messages
    assert [p.seq for p in poses] == list(range(len(shown)))
    assert {p.source for p in poses} == {"mediapipe"}
    assert [p.detected for p in poses] == shown
    for pose in poses:
        if pose.detected:
            assert len(pose.landmarks) == 21
            # the hand's box in the photo (tests/fixtures/hand/SOURCE.md): x 0-549, y 0-454 px
            assert 0.0 <= pose.center[0] <= 550 / 640 and 0.0 <= pose.center[1] <= 455 / 480
    assert frames.items and frames.bad == 0  # the monitor JPEGs, with the landmarks drawn
