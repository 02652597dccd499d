"""The Rerun bridge: each message type lands on its entity paths, read back from a real .rrd."""

import socket
import uuid
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from services.core import messages as m
from services.core.keys import Keys
from services.model.geometry import OptionsLayout
from services.monitor.bridge import (
    ARM_BASE,
    ENTITIES,
    EYES,
    FRAME_SIZE,
    GAZE_LENGTH,
    NOT_SHOWN,
    RED,
    TIMELINE,
    TRIAL_TIMELINE,
    RerunBridge,
    blueprint,
    box_colour,
    rrd_rows,
)
from services.monitor.inbox import Inbox, Item, lane_of
from services.monitor.service import Monitor
from services.monitor.sinks import ViewerWatch
from services.views.entities import APPLICATION_ID

T0 = 1_795_448_811_000_000_000
PAPER = ("red", "blue")
LANDMARKS = ((0.5, 0.7), (0.52, 0.71), (0.51, 0.69))


def _jpeg(width: int, height: int, value: int = 90) -> bytes:
    img = np.full((height, width, 3), value, np.uint8)
    cv2.rectangle(img, (width // 4, height // 4), (width // 2, height // 2), (0, 0, 255), -1)
    return cv2.imencode(".jpg", img)[1].tobytes()


JPEG = _jpeg(*FRAME_SIZE)


def _record(tmp_path, messages, name="b.rrd"):
    """Log (topic, message) pairs through a bridge into an .rrd file; return its path."""
    path = tmp_path / name
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    rec.set_sinks(rr.FileSink(str(path)), default_blueprint=blueprint())
    bridge = RerunBridge(rec)
    bridge.log_styles()
    for topic, msg in messages:
        bridge.log(topic, msg)
    rec.flush()
    rec.disconnect()
    return path, bridge


def _hand(seq, detected=True):
    if not detected:
        return m.HandPose(seq=seq, t_ns=T0 + seq * 8_000_000, source="sim")
    return m.HandPose(
        seq=seq, t_ns=T0 + seq * 8_000_000, detected=True, center=(0.51, 0.7), landmarks=LANDMARKS
    )


def _column(path, entity, column):
    """Every value of one column of one entity's temporal rows, in file order."""
    out = []
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == entity and not chunk.is_static:
            batch = chunk.to_record_batch()
            i = batch.schema.get_field_index(column)
            out += batch.column(i).to_pylist() if i >= 0 else [None] * batch.num_rows
    return out


def _values(path, entity, column):
    """The rows of one entity that carry `column` (a style-only row does not)."""
    return [v for v in _column(path, entity, column) if v is not None]


def test_two_option_opinions_are_time_series_of_the_signed_value(tmp_path):
    """Over the paper's two options an opinion is its signed z, plotted as it always was."""
    msgs = [("experiment/trial",
             m.TrialEvent(seq=0, t_ns=T0, options=PAPER, phase="setup", trial=3))]
    for i in range(5):
        for j, topic in enumerate(("decision/z_h", "decision/z_r", "decision/b_r")):
            cls = m.Observed if topic == "decision/z_h" else m.Opinions
            msgs.append((topic, cls(seq=i, t_ns=T0 + i * 1000, src_seq=i,
                                    **m.signed_fields(i + j / 10))))
    path, bridge = _record(tmp_path, msgs)
    assert not bridge.bars_sent  # two options: no bar charts
    rows, static = rrd_rows(path)
    for topic in ("decision/z_h", "decision/z_r", "decision/b_r"):
        assert rows["/" + ENTITIES[topic]] == 5
        assert static["/" + ENTITIES[topic]] == 1  # the series name and colour
    times = _column(path, "/opinion/z_r", TIMELINE)
    assert [np.datetime64(t, "ns").astype(np.int64) for t in times] == [
        T0 + i * 1000 for i in range(5)
    ]
    assert set(_column(path, "/opinion/z_r", TRIAL_TIMELINE)) == {3}
    assert _column(path, "/opinion/b_r", "Scalars:scalars") == [[i + 0.2] for i in range(5)]


def test_every_message_type_reaches_its_entities(tmp_path):
    msgs = [
        (
            "vision/layout",
            m.Layout(seq=0, t_ns=T0, options=PAPER,
                     boxes=((0.7, 0.1, 0.9, 0.3), (0.1, 0.1, 0.3, 0.3))),
        ),
        (
            "vision/layout",
            m.Layout(seq=1, t_ns=T0 + 1, options=PAPER,
                     boxes=((0.7, 0.1, 0.9, 0.3), (0.1, 0.1, 0.3, 0.3))),
        ),
        ("vision/hand", _hand(1)),
        ("vision/hand", _hand(2, detected=False)),
        ("vision/hand", _hand(3)),
        (
            "actuation/cmd",
            m.ArmCommandMsg(seq=0, t_ns=T0, action="move", direction=1, target="red"),
        ),
        (
            "actuation/cmd",
            m.ArmCommandMsg(seq=1, t_ns=T0 + 5, action="move", direction=1, target="red"),
        ),
        ("actuation/state", m.ArmStateMsg(seq=0, t_ns=T0, phase="move", moving=True)),
        ("actuation/state", m.ArmStateMsg(seq=1, t_ns=T0 + 9, phase="move", moving=True)),
        (
            "actuation/state",
            m.ArmStateMsg(
                seq=2, t_ns=T0 + 20, phase="stop", safe_stop=True, safety_reason="stale (257 ms)"
            ),
        ),
        (
            "actuation/state",
            m.ArmStateMsg(
                seq=3, t_ns=T0 + 30, phase="stop", safe_stop=True, safety_reason="stale (301 ms)"
            ),
        ),
        ("actuation/state", m.ArmStateMsg(seq=4, t_ns=T0 + 40, phase="idle")),
        ("actuation/press", m.PressMsg(seq=0, t_ns=T0, option="red", trial=1)),
        ("eyes/cmd", m.GazeMsg(seq=0, t_ns=T0, yaw=0.3, pitch=-0.2, level="low", trial=1)),
        ("eyes/cmd", m.GazeMsg(seq=1, t_ns=T0 + 1, yaw=0.3, pitch=-0.2, level="low", trial=1)),
        ("eyes/state", m.EyesStateMsg(seq=0, t_ns=T0, angles_deg=(100, 80, 100, 80))),
        (
            "eyes/state",
            m.EyesStateMsg(seq=1, t_ns=T0 + 2, clamped=("left_pan",), fault="servo timeout"),
        ),
        (
            "experiment/trial",
            m.TrialEvent(seq=0, t_ns=T0, options=PAPER, phase="countdown", trial=1, text="3"),
        ),
        (
            "experiment/result",
            m.TrialResult(seq=0, t_ns=T0, options=PAPER, trial=1, robot="red", human="red",
                          outcome="C"),
        ),
        ("safety/estop", m.Estop(seq=0, t_ns=T0, engaged=True, reason="test", source="pytest")),
        ("safety/estop", m.Estop(seq=1, t_ns=T0 + 1, engaged=False)),
    ]
    if hasattr(m, "VisionFrame"):  # the vision service's frames, where the contract has them
        msgs.append(("vision/frame", _frame(0, JPEG, *FRAME_SIZE)))
    path, bridge = _record(tmp_path, msgs)
    rows, static = rrd_rows(path)
    assert bridge.logged == len(msgs)
    assert static["/table/buzzers"] == 1 and static["/table/commit_line"] == 1  # once: unchanged
    assert rows["/table/hand"] == 2  # the undetected pose draws nothing
    assert len(_values(path, "/table/arm", "Points2D:positions")) == 5
    assert len(_values(path, "/table/arm", "Points2D:colors")) == 3  # normal, stopped, normal
    assert rows["/state/arm"] == 3  # move, stop, idle: changes only
    assert rows["/log/arm"] == 1  # the repeated command is not logged twice
    assert rows["/eyes/gaze/yaw"] == 2 and rows["/eyes/gaze/pitch"] == 2
    assert rows["/state/gaze"] == 1
    assert rows["/eyes/servos"] == 2
    assert _column(path, "/eyes/servos", "Scalars:scalars")[0] == [100, 80, 100, 80]
    assert rows["/state/trial"] == 1
    assert rows["/log/result"] == 1
    safety = [t[0] for t in _column(path, "/log/safety", "TextLog:text")]
    assert safety == [
        "arm: SAFE STOP (stale (257 ms))",  # the second, only its number changed: not repeated
        "arm: safe stop cleared",
        "eyes: FAULT servo timeout",
        "eyes: servo target clamped: left_pan",
        "ESTOP by pytest: test",
        "estop released",
    ]
    trial_log = [t[0] for t in _column(path, "/log/trial", "TextLog:text")]
    assert trial_log == ["trial 1: robot pressed red", "trial 1 countdown 3"]
    if hasattr(m, "VisionFrame"):
        assert rows["/camera/frame"] == 1
        assert _column(path, "/camera/frame", "EncodedImage:media_type") == [["image/jpeg"]]


def _frame(seq, jpeg, width, height, t_ns=T0):
    return m.VisionFrame(seq=seq, t_ns=t_ns + seq, jpeg=jpeg, width=width, height=height)


def _images(path):
    """Every camera/frame image of the recording, decoded."""
    out = []
    for blob in _values(path, "/camera/frame", "EncodedImage:blob"):
        data = np.asarray(blob[0], dtype=np.uint8)
        out.append(cv2.imdecode(data, cv2.IMREAD_COLOR))
    return out


def test_only_visions_frames_are_recorded_not_the_simulated_camera(tmp_path):
    """`nod run --render`: the sim's 30 Hz full-size camera is vision's input, not the monitor's."""
    msgs = []
    for i in range(30):
        msgs.append(("sim/camera", _frame(i, _jpeg(640, 480), 640, 480)))
        if i % 15 == 0:  # vision's low-rate annotated frames
            msgs.append(("vision/frame", _frame(i, JPEG, *FRAME_SIZE)))
    path, bridge = _record(tmp_path, msgs)
    rows, static = rrd_rows(path)
    assert rows["/camera/frame"] == 2
    assert bridge.logged == 2  # the sim/camera messages are not even counted
    image_entities = {
        chunk.entity_path
        for chunk in RrdReader(path).stream()
        if any("Image" in field.name for field in chunk.to_record_batch().schema)
    }
    assert image_entities == {"/camera/frame"}
    assert [img.shape for img in _images(path)] == [(240, 320, 3)] * 2


def test_frames_are_logged_at_one_size_whatever_size_they_come_in(tmp_path):
    sizes = [FRAME_SIZE, (640, 480), (160, 90), (400, 300), (240, 320), FRAME_SIZE]
    msgs = [("vision/frame", _frame(i, _jpeg(w, h), w, h)) for i, (w, h) in enumerate(sizes)]
    broken = b"\xff\xd8\xff\xe0" + b"\x00" * 32 + b"\xff\xd9"  # a JPEG's header, no image
    msgs.append(("vision/frame", _frame(9, broken, 320, 240)))
    path, bridge = _record(tmp_path, msgs)
    images = _images(path)
    assert [img.shape for img in images] == [(240, 320, 3)] * len(sizes)  # the broken one: gone
    assert bridge.frames_dropped == 1
    blobs = _values(path, "/camera/frame", "EncodedImage:blob")
    assert bytes(blobs[0][0]) == JPEG  # already the right size: the very same bytes
    # 640x480 is scaled to fill 320x240; 16:9 is letterboxed: black bands above and below
    wide = images[2]
    assert wide[:20].max() < 10 and wide[-20:].max() < 10 and wide[120, 40:280].mean() > 60
    tall = images[4]  # 3:4, pillarboxed: black bands left and right
    assert tall[:, :60].max() < 10 and tall[:, -60:].max() < 10
    assert "not a JPEG" in _column(path, "/log/services", "TextLog:text")[0][0]


def test_the_arm_is_a_segment_from_its_base_and_the_gaze_arrows_from_the_eyes(tmp_path):
    msgs = [
        ("actuation/state", m.ArmStateMsg(seq=0, t_ns=T0, ee=(0.79, 0.19), phase="move")),
        ("actuation/state", m.ArmStateMsg(seq=1, t_ns=T0 + 1, ee=(0.5, 0.08), safe_stop=True)),
        ("eyes/cmd", m.GazeMsg(seq=0, t_ns=T0, yaw=0.0, level="neutral")),
        ("eyes/cmd", m.GazeMsg(seq=1, t_ns=T0 + 1, yaw=0.53, pitch=-0.53, level="low")),
        ("eyes/cmd", m.GazeMsg(seq=2, t_ns=T0 + 2, yaw=-0.72, pitch=0.72, level="significant")),
    ]
    path, _ = _record(tmp_path, msgs)
    rows, static = rrd_rows(path)
    assert static["/table/arm_link"] == 1 and static["/table/gaze"] == 1  # their styles
    strips = _values(path, "/table/arm_link", "LineStrips2D:strips")
    assert np.allclose(strips[0], [[ARM_BASE, (0.79, 0.19)]])
    assert np.allclose(strips[1], [[ARM_BASE, (0.5, 0.08)]])
    assert ARM_BASE == (0.5, 0.0)  # the middle of the robot's (top) edge of the table
    colours = _values(path, "/table/arm_link", "LineStrips2D:colors")
    assert len(colours) == 2  # normal, then red while safe-stopped: like the end effector
    origins = _values(path, "/table/gaze", "Arrows2D:origins")
    vectors = [np.array(v) for v in _values(path, "/table/gaze", "Arrows2D:vectors")]
    assert len(origins) == len(vectors) == 3
    for o in origins:
        assert np.allclose(o, EYES)  # one arrow from each eye
    straight, red, blue = vectors
    assert np.allclose(straight, [(0.0, GAZE_LENGTH)] * 2)  # yaw 0: at the participant (+y)
    # yaw +0.53 (toward red, the right of the image): x > 0; -0.72 (toward blue): x < 0
    assert np.allclose(red, [(GAZE_LENGTH * np.sin(0.53), GAZE_LENGTH * np.cos(0.53))] * 2)
    assert np.allclose(blue, [(GAZE_LENGTH * np.sin(-0.72), GAZE_LENGTH * np.cos(-0.72))] * 2)
    assert red[0][0] > 0 > blue[0][0]
    # an eye 0.05 off the middle, looking at red, points into red's box's column (x 0.72-0.86)
    tip = np.array(EYES[1]) + red[1] * (0.19 / red[1][1])
    assert 0.6 < tip[0] < 0.9


def _one_trial(n_options):
    """A layout, one trial of O = the last option, the arm, its press and the result.

    One key space for any option count: the same keys and messages, the options by name.
    """
    names = ("red", "blue", "green", "yellow")[:n_options]
    last = names[-1]
    layout = m.layout_fields(names, OptionsLayout.row(n_options))
    return names, [
        ("vision/layout", m.Layout(seq=0, t_ns=T0, **layout)),
        ("experiment/trial", m.TrialEvent(seq=0, t_ns=T0, options=names, phase="setup", trial=4,
                                          mode="consensus", option=last, text="low")),
        ("actuation/state", m.ArmStateMsg(seq=0, t_ns=T0 + 1, ee=(0.3, 0.2), phase="move",
                                          target=last)),
        ("actuation/state", m.ArmStateMsg(seq=1, t_ns=T0 + 2, ee=(0.2, 0.2), safe_stop=True,
                                          phase="stop", safety_reason="stale (257 ms)")),
        ("actuation/press", m.PressMsg(seq=0, t_ns=T0 + 3, option=last, trial=4)),
        ("experiment/result", m.TrialResult(seq=0, t_ns=T0 + 4, options=names, trial=4,
                                            mode="consensus", option=last, robot=last,
                                            human=last, outcome="C", score=2)),
    ]


@pytest.mark.parametrize("n_options", [2, 3, 4])
def test_the_table_and_the_trial_read_alike_for_any_option_count(tmp_path, n_options):
    names, msgs = _one_trial(n_options)
    path, bridge = _record(tmp_path, msgs + msgs[:1])  # the layout again: not logged twice
    rows, static = rrd_rows(path)
    assert bridge.trial == 4 and bridge.option_names == names
    assert static["/table/buzzers"] == 1 and static["/table/commit_line"] == 1
    boxes = [c for c in RrdReader(path).stream() if c.entity_path == "/table/buzzers"]
    batch = boxes[0].to_record_batch()
    labels = batch.column(batch.schema.get_field_index("Boxes2D:labels")).to_pylist()
    assert labels == [list(names)]
    assert box_colour("red") == RED  # the paper's red whatever the option count
    assert len(_values(path, "/table/arm", "Points2D:positions")) == 2
    assert len(_values(path, "/table/arm", "Points2D:colors")) == 2  # normal, then stopped
    assert rows["/state/arm"] == 2 and rows["/state/trial"] == 1
    last = names[-1]
    assert [t[0] for t in _column(path, "/log/trial", "TextLog:text")] == [
        f"trial 4 setup: consensus O={last}, gaze low", f"trial 4: robot pressed {last}"]
    assert [t[0] for t in _column(path, "/log/result", "TextLog:text")] == [
        f"trial 4 [consensus O={last}]: robot {last}, human {last} → C (switches 0, "
        "violations 0, score 2)"]
    assert [t[0] for t in _column(path, "/log/safety", "TextLog:text")] == [
        "arm: SAFE STOP (stale (257 ms))"]


def test_opinions_over_three_options_are_bar_charts_and_the_layout_shows_bars(tmp_path):
    """The same keys as the paper's: a vector over three options is a bar chart, not a series."""
    names = ("red", "blue", "green")
    msgs = []
    for i in range(4):
        for topic in ("decision/z_h", "decision/z_r", "decision/b_r"):
            cls = m.Observed if topic == "decision/z_h" else m.Opinions
            values = (0.2 * i, -0.1 * i, -0.1 * i)
            msgs.append((topic, cls(seq=i, t_ns=T0 + i, options=names, values=values)))
    path, bridge = _record(tmp_path, msgs)
    rows, _ = rrd_rows(path)
    for q in ("z_h", "z_r", "b_r"):
        assert rows["/" + ENTITIES[f"bars/{q}"]] == 4
        assert "/" + ENTITIES[f"decision/{q}"] not in rows  # no time series of a vector
    assert bridge.bars_sent
    tensor = _column(path, "/bars/z_r", "BarChart:values")[-1][0]
    assert tensor["shape"] == [3]  # one bar per option, the latest vector
    assert tensor["buffer"] == pytest.approx([0.6, -0.3, -0.3])
    bars = [str(v.origin) for v in _views(blueprint(bars=True)) if "BarChart" in type(v).__name__]
    assert bars == ["bars/z_h", "bars/z_r", "bars/b_r"]
    paper = {str(v.origin) for v in _views(blueprint())}
    assert {str(v.origin) for v in _views(blueprint(bars=True))} - paper == set(bars)


def _views(bp, having: str = "origin"):
    """Every view of a blueprint that has the attribute `having`, depth first."""
    views = []

    def walk(node):
        for child in getattr(node, "contents", []) or []:
            walk(child)
        if hasattr(node, having):
            views.append(node)

    walk(bp.root_container)
    return views


def test_the_table_view_shows_only_the_live_arm_and_gaze():
    """The table keeps a 3 s trail of hand and end effector, but not of segments and arrows."""
    views = _views(blueprint(), having="visualizer_overrides")
    table = next(v for v in views if str(v.origin) == "table")
    assert set(table.visualizer_overrides) == {ENTITIES["arm_link"], ENTITIES["gaze"]}
    camera = next(v for v in views if str(v.origin) == "camera")
    assert camera is not None


def test_recording_carries_the_blueprint(tmp_path):
    path, _ = _record(tmp_path, [("vision/hand", _hand(1))])
    reader = RrdReader(path)
    assert [b.application_id for b in reader.blueprints()] == [APPLICATION_ID]
    assert reader.store() is not None  # a footer: the file was closed cleanly


def test_note_without_any_message_still_logs(tmp_path):
    path = tmp_path / "n.rrd"
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    rec.set_sinks(rr.FileSink(str(path)))
    RerunBridge(rec).note("service sim up", t_ns=T0)
    rec.disconnect()
    assert rrd_rows(path)[0]["/log/services"] == 1


# --- the inbox --------------------------------------------------------------------------------


def test_lanes():
    assert lane_of("vision/hand") == "hand"
    assert lane_of("vision/frame") == "frame"
    assert lane_of("decision/z_h") == "events"
    assert lane_of("safety/estop") == "events"


def test_hand_lane_drops_the_oldest_and_counts():
    box = Inbox(events=10, hand=3, frame=1)
    for i in range(5):
        box.put("hand", Item("vision/hand", bytes([i])))
    assert box.dropped["hand"] == 2
    assert [it.payload for it in box.get_batch(0)] == [b"\x02", b"\x03", b"\x04"]


def test_event_lane_never_evicts_and_counts_what_it_refuses():
    box = Inbox(events=2, hand=1, frame=1)
    assert box.put("events", Item("decision/z_h", b"a"))
    assert box.put("events", Item("decision/z_h", b"b"))
    assert not box.put("events", Item("decision/z_h", b"c"))
    assert box.dropped["events"] == 1
    assert [it.payload for it in box.get_batch(0)] == [b"a", b"b"]


def test_events_come_before_hand_poses_and_close_wakes_the_consumer():
    box = Inbox()
    box.put("hand", Item("vision/hand", b"h"))
    box.put("events", Item("decision/z_h", b"e"))
    assert [it.topic for it in box.get_batch(0)] == ["decision/z_h", "vision/hand"]
    box.close()
    assert box.get_batch(5.0) == []  # returns at once: closed and empty
    assert not box.put("events", Item("decision/z_h", b"late"))


def test_the_monitor_skips_the_simulated_camera_before_queueing_it():
    class Sample:
        def __init__(self, key, payload):
            self.key_expr = key
            self.payload = SimpleNamespace(to_bytes=lambda: payload)

    rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    monitor = Monitor(None, Keys("rig1"), RerunBridge(rec), Inbox())
    frame = m.encode(_frame(0, JPEG, *FRAME_SIZE))
    for _ in range(30):
        monitor._on_sample(Sample("nod/rig1/sim/camera", frame))
    monitor._on_sample(Sample("nod/rig1/vision/frame", frame))
    assert [it.topic for it in monitor.inbox.get_batch(0)] == ["vision/frame"]
    assert monitor.skipped == {"sim/camera": 30}
    assert "sim/camera" in NOT_SHOWN


def test_capacity_must_be_positive():
    with pytest.raises(ValueError, match="capacity"):
        Inbox(hand=0)


# --- viewer watch -----------------------------------------------------------------------------


def test_viewer_watch_counts_how_long_a_viewer_port_is_closed():
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        watch = ViewerWatch([f"rerun+http://127.0.0.1:{port}/proxy"], period_s=0.0)
        assert watch.gone_for(now=100.0) == 0.0
    assert watch.gone_for(now=101.0) == 0.0  # first failed probe: gone since now
    assert watch.gone_for(now=131.0) == 30.0
    assert ViewerWatch([]).gone_for() == 0.0  # nothing to watch
