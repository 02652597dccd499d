"""The Rerun bridge: each message type lands on its entity paths, read back from a real .rrd."""

import socket
import uuid

import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from services.core import messages as m
from services.monitor.bridge import (
    APPLICATION_ID,
    ENTITIES,
    TIMELINE,
    TRIAL_TIMELINE,
    RerunBridge,
    blueprint,
    rrd_rows,
)
from services.monitor.inbox import Inbox, Item, lane_of
from services.monitor.sinks import ViewerWatch

T0 = 1_795_448_811_000_000_000
LANDMARKS = ((0.5, 0.7), (0.52, 0.71), (0.51, 0.69))
JPEG = b"\xff\xd8\xff\xe0" + b"\x00" * 32 + b"\xff\xd9"


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


def test_scalars_are_time_series_on_the_message_time_and_trial(tmp_path):
    msgs = [("experiment/trial", m.TrialEvent(seq=0, t_ns=T0, phase="setup", trial=3))]
    for i in range(5):
        for j, topic in enumerate(("decision/z_h", "decision/z_r", "decision/b_r")):
            msgs.append((topic, m.Scalar(seq=i, t_ns=T0 + i * 1000, value=i + j / 10, src_seq=i)))
    path, _ = _record(tmp_path, msgs)
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
            m.Layout(seq=0, t_ns=T0, red=(0.7, 0.1, 0.9, 0.3), blue=(0.1, 0.1, 0.3, 0.3)),
        ),
        (
            "vision/layout",
            m.Layout(seq=1, t_ns=T0 + 1, red=(0.7, 0.1, 0.9, 0.3), blue=(0.1, 0.1, 0.3, 0.3)),
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
        ("actuation/press", m.PressMsg(seq=0, t_ns=T0, colour="red", trial=1)),
        ("eyes/cmd", m.GazeMsg(seq=0, t_ns=T0, yaw=0.3, pitch=-0.2, level="low", trial=1)),
        ("eyes/cmd", m.GazeMsg(seq=1, t_ns=T0 + 1, yaw=0.3, pitch=-0.2, level="low", trial=1)),
        ("eyes/state", m.EyesStateMsg(seq=0, t_ns=T0, angles_deg=(100, 80, 100, 80))),
        (
            "eyes/state",
            m.EyesStateMsg(seq=1, t_ns=T0 + 2, clamped=("left_pan",), fault="servo timeout"),
        ),
        ("experiment/trial", m.TrialEvent(seq=0, t_ns=T0, phase="countdown", trial=1, text="3")),
        (
            "experiment/result",
            m.TrialResult(seq=0, t_ns=T0, trial=1, robot="red", human="red", outcome="C"),
        ),
        ("safety/estop", m.Estop(seq=0, t_ns=T0, engaged=True, reason="test", source="pytest")),
        ("safety/estop", m.Estop(seq=1, t_ns=T0 + 1, engaged=False)),
    ]
    if hasattr(m, "VisionFrame"):  # the vision service's frames, where the contract has them
        msgs.append(("vision/frame", m.VisionFrame(seq=0, t_ns=T0, jpeg=JPEG, width=8, height=8)))
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
