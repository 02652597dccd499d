"""The recording format, the recorder's validation, the replay's key choice, the store's links.

Whole sessions recorded and replayed over a real router: tests/integration/test_record_replay.py.
"""

from __future__ import annotations

import base64
import json
import math
import sqlite3

import msgspec
import pytest
from mcap.reader import make_reader
from mcap.records import Channel, Schema

from services.core import messages as m
from services.core.contract import TOPICS
from services.core.keys import topic_of
from services.model.decision import DecisionModel
from services.recording.json_channels import schema_data
from services.recording.mcap_io import FILE_METADATA, McapIn, McapOut, channel_metadata
from services.recording.record import Recorder
from services.recording.selection import input_topics, select_topics
from services.recording.through import through_decision
from services.store import Store

JPEG = b"\xff\xd8\xff\xe0" + b"\x00" * 60
PAPER = ("red", "blue")


def _pose(seq: int, t_ns: int, x: float = 0.5, y: float = 0.8) -> m.HandPose:
    pts = ((x - 0.01, y), (x + 0.01, y), (x, y - 0.02))
    return m.HandPose(seq=seq, t_ns=t_ns, detected=True, center=(x, y - 0.0067), landmarks=pts)


def test_inputs_are_what_the_services_under_test_need_from_outside():
    # the camera's: the hand and the table (any number of boxes, one key: schema 3)
    assert input_topics() == ("vision/hand", "vision/layout")
    every = set(TOPICS)
    assert select_topics(every, None, True) == {"vision/hand", "vision/layout"}
    # a whole replay leaves the e-stop release out unless it is named
    assert "safety/release" not in select_topics(every, None, False)
    assert "safety/estop" in select_topics(every, None, False)
    assert select_topics(every, ["safety/*"], False) == {"safety/estop", "safety/release"}
    assert select_topics(every, ["nod/rigX/vision/hand"], False) == {"vision/hand"}
    assert select_topics(every, ["vision/hand"], True) == {"vision/hand"}
    with pytest.raises(ValueError, match="not a key expression"):
        select_topics(every, ["vi*/hand"], False)


def test_the_recorder_writes_each_message_as_json_per_key_and_keeps_invalid_payloads_apart(
    tmp_path,
):
    path = tmp_path / "r.mcap"
    out = McapOut(path)
    out.metadata(FILE_METADATA, {"rig": "rig1", "params": {"a": 1}})
    rec = Recorder(out, images=True)
    pose = m.encode(_pose(7, 1_000))
    rec.add("nod/rig1/vision/hand", pose, 5_000)
    event = m.encode(m.TrialEvent(seq=0, t_ns=2_000, phase="setup", trial=1, session="s1",
                                  options=PAPER))
    rec.add("nod/rig1/experiment/trial", event, 6_000)
    rec.add("nod/rig1/experiment/trial", event, 6_500)  # the session is noted once
    rec.add("nod/rig1/vision/hand", b"\xc1garbage", 7_000)
    rec.add("nod/rig1/not/a/key", pose, 8_000)
    frame = m.VisionFrame(seq=3, t_ns=3_000, jpeg=JPEG, width=64, height=48)
    rec.add("nod/rig1/vision/frame", m.encode(frame), 9_000)
    out.finish()
    assert rec.sessions == ["s1"]
    assert rec.invalid == {"nod/rig1/vision/hand": 1, "nod/rig1/not/a/key": 1}

    with path.open("rb") as fh:
        reader = make_reader(fh)
        rows = [(c.topic, c, s, msg) for s, c, msg in reader.iter_messages()]
        meta = [(md.name, md.metadata) for md in reader.iter_metadata()]
    valid = [(t, msg) for t, c, _s, msg in rows
             if c.message_encoding == "json" and "derived_from" not in c.metadata]
    as_json = [(t, json.loads(msg.data), msg.log_time, msg.publish_time, msg.sequence)
               for t, msg in valid]
    assert as_json == [
        ("nod/rig1/vision/hand", msgspec.msgpack.decode(pose), 5_000, 1_000, 7),
        ("nod/rig1/experiment/trial", msgspec.msgpack.decode(event), 6_000, 2_000, 0),
        ("nod/rig1/experiment/trial", msgspec.msgpack.decode(event), 6_500, 2_000, 0),
        ("nod/rig1/vision/frame", {**msgspec.msgpack.decode(m.encode(frame)),
                                   "jpeg": base64.b64encode(JPEG).decode()}, 9_000, 3_000, 3),
    ]
    schemas = {t: s.name for t, c, s, _ in rows if s is not None}
    assert schemas["nod/rig1/vision/hand"] == "HandPose"
    assert schemas["nod/rig1/vision/frame/image"] == "foxglove.CompressedImage"
    invalid = [(t, c.metadata["invalid"], msg.publish_time, msg.log_time)
               for t, c, s, msg in rows if "invalid" in c.metadata]
    assert invalid[0][0] == "nod/rig1/vision/hand" and "not valid msgpack" in invalid[0][1]
    assert invalid[0][2] == invalid[0][3] == 7_000  # publish_time = log_time
    assert invalid[1][:2] == ("nod/rig1/not/a/key", "not a key of the contract")
    (image,) = [msg for t, c, s, msg in rows if t.endswith("/image")]
    body = json.loads(image.data)
    assert base64.b64decode(body["data"]) == JPEG and body["format"] == "jpeg"
    assert body["timestamp"] == {"sec": 0, "nsec": 3_000}
    assert [name for name, _ in meta] == ["nod", "nod.session"]
    assert json.loads(meta[0][1]["params"]) == {"a": 1}
    # the players read only the contract's messages, as the msgpack payloads they travelled as
    assert [(e.key, e.payload) for e in McapIn(path) if e.valid] == [
        ("nod/rig1/vision/hand", pose), ("nod/rig1/experiment/trial", event),
        ("nod/rig1/experiment/trial", event), ("nod/rig1/vision/frame", m.encode(frame))]


def test_a_file_cut_short_reads_up_to_its_last_complete_chunk(tmp_path):
    path = tmp_path / "full.mcap"
    out = McapOut(path)
    out.metadata(FILE_METADATA, {"rig": "rig1"})
    sizes: list[int] = []
    for i in range(300):
        out.write_message("nod/rig1/vision/hand", _pose(i, i), 10_000 + i)
        if i % 100 == 99:
            out.flush()  # three chunks
            sizes.append(out.size())
    out.finish()
    whole = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: sizes[1] + 100])  # the third chunk is cut short
    read = McapIn(cut)
    seqs = [m.decode(m.HandPose, e.payload).seq for e in read]
    assert seqs == list(range(200)) and not read.complete and read.truncated
    assert read.file_metadata() == {"rig": "rig1"}
    full = McapIn(path)
    assert sum(1 for _ in full) == 300 and full.complete and full.truncated is None


def test_through_decision_recomputes_what_the_model_says(tmp_path):
    src = tmp_path / "src.mcap"
    out = McapOut(src)
    out.metadata(FILE_METADATA, {"rig": "rig1"})
    t0 = 1_000_000_000
    events = [
        (0, m.TrialEvent(seq=0, t_ns=t0, phase="setup", trial=1, mode="consensus",
                         option="red", options=PAPER)),
        (1, m.TrialEvent(seq=1, t_ns=t0 + 10_000_000, phase="go", trial=1, mode="consensus",
                         option="red", options=PAPER)),
    ]
    for i, ev in events:
        out.write_message("nod/rig1/experiment/trial", ev, i)
    poses = [_pose(i, t0 + 20_000_000 + i * 33_000_000, x=0.5 - 0.01 * i, y=0.8 - 0.02 * i)
             for i in range(20)]
    for i, pose in enumerate(poses):
        out.write_message("nod/rig1/vision/hand", pose, 10 + i)
        bogus = m.Opinions(seq=i, t_ns=pose.t_ns, src_seq=pose.seq, **m.signed_fields(99.0))
        out.write_message("nod/rig1/decision/z_r", bogus, 10 + i)
    out.finish()

    res = through_decision(src, tmp_path / "out.mcap", None)
    model = DecisionModel()
    model.on_trial("go", "consensus", "red")
    expected = [model.on_hand(p.t_ns, p.landmarks).z_r for p in poses]
    got = [m.decode(m.Opinions, e.payload) for e in McapIn(tmp_path / "out.mcap")
           if topic_of(e.key) == "decision/z_r"]
    assert [s.signed for s in got] == expected  # the recorded 99.0 are gone
    assert [s.src_seq for s in got] == [p.seq for p in poses]
    assert res.poses == 20 and res.left_out == 20 and res.recomputed == 60
    (trial,) = res.trials
    assert trial.final()[1] == (expected[-1], model.b_r)
    assert "trial 1 consensus O=red" in trial.line()


def _v1(**fields) -> bytes:
    """A payload as the paper's keys carried it before schema 3 (schema 1)."""
    return msgspec.msgpack.encode({"v": 1, "seq": 0, **fields})


def write_old(out: McapOut, key: str, log_time: int, publish_time: int, payload: bytes) -> None:
    """A payload as recordings kept it before JSON channels: msgpack, as it travelled."""
    topic = topic_of(key)
    assert topic is not None
    cls = TOPICS[topic].message
    channel = Channel(id=0, topic=key, message_encoding="msgpack", schema_id=0,
                      metadata=channel_metadata(topic))
    schema = Schema(id=0, name=cls.__name__, encoding="jsonschema", data=schema_data(cls))
    out.write(out.copy_channel(channel, schema), log_time, publish_time, payload)


def test_a_schema_1_recording_reads_replays_and_goes_through_decision_in_todays_schema(tmp_path):
    src = tmp_path / "old.mcap"
    out = McapOut(src)
    out.metadata(FILE_METADATA, {"rig": "rig1"})
    t0 = 1_000_000_000
    red, blue = (0.1, 0.05, 0.3, 0.25), (0.7, 0.05, 0.9, 0.25)
    write_old(out, "nod/rig1/vision/layout", 0, t0,
              _v1(t_ns=t0, red=red, blue=blue, commit_y=0.45))
    for i, phase in enumerate(("setup", "go")):
        write_old(out, "nod/rig1/experiment/trial", 1 + i, t0 + i,
                  _v1(t_ns=t0 + i, phase=phase, trial=1, mode="consensus", option="blue",
                      text="", session="s1"))
    poses = [_pose(i, t0 + 20_000_000 + i * 33_000_000, x=0.5 + 0.01 * i) for i in range(10)]
    for i, pose in enumerate(poses):
        write_old(out, "nod/rig1/vision/hand", 10 + i, pose.t_ns, m.encode(pose))
        write_old(out, "nod/rig1/decision/z_r", 10 + i, pose.t_ns,
                  _v1(t_ns=pose.t_ns, value=-0.5 * i, src_seq=pose.seq))
    write_old(out, "nod/rig1/actuation/press", 40, t0 + 10**9,
              _v1(t_ns=t0 + 10**9, colour="blue", trial=1))
    out.finish()

    read = {topic_of(e.key): m.decode(TOPICS[topic_of(e.key)].message, e.payload)
            for e in McapIn(src)}
    assert read["vision/layout"].options == ("red", "blue")
    assert read["vision/layout"].boxes == (red, blue)
    assert read["experiment/trial"].options == ("red", "blue")
    assert read["experiment/trial"].option == "blue"
    assert read["decision/z_r"].values == (-4.5, 4.5) and read["decision/z_r"].signed == -4.5
    assert read["actuation/press"].option == "blue"

    res = through_decision(src, tmp_path / "out.mcap", None)
    model = DecisionModel()
    model.set_layout(read["vision/layout"].paper_table())
    model.on_trial("go", "consensus", "blue")
    expected = [model.on_hand(p.t_ns, p.landmarks).z_r for p in poses]
    recorded, _ = res.trials[0].final()
    assert recorded is not None and recorded[0] == -4.5 and math.isnan(recorded[1])
    copied = [e for e in McapIn(tmp_path / "out.mcap")]
    for e in copied:  # every message of the derived file is of today's schema and form
        assert e.channel.message_encoding == "json"
        assert json.loads(e.message.data)["v"] == m.SCHEMA_VERSION
    got = [m.decode(m.Opinions, e.payload).signed for e in copied
           if topic_of(e.key) == "decision/z_r"]
    assert got == expected


def test_a_recording_of_three_options_does_not_go_through_the_paper_engine(tmp_path):
    src = tmp_path / "three.mcap"
    out = McapOut(src)
    out.metadata(FILE_METADATA, {"rig": "rig1"})
    ev = m.TrialEvent(seq=0, t_ns=5, phase="setup", trial=1, mode="consensus", option="green",
                      options=("red", "blue", "green"))
    out.write_message("nod/rig1/experiment/trial", ev, 0)
    out.finish()
    with pytest.raises(ValueError, match="table of N options .*red,blue,green"):
        through_decision(src, tmp_path / "out.mcap", None)
    assert not (tmp_path / "out.mcap").exists()


def test_the_store_links_recordings_to_sessions_and_adds_the_table_to_old_files(tmp_path):
    db = tmp_path / "s.sqlite"
    store = Store(db)
    store.begin_session("s1", "P01", "rig1", 1, 10, {})
    store.add_recording("s1", tmp_path / "a.mcap", 20)
    store.add_recording("s1", tmp_path / "a-2.mcap", 30)
    assert store.recordings("s1") == [(str(tmp_path / "a.mcap"), 20),
                                      (str(tmp_path / "a-2.mcap"), 30)]
    assert store.recordings("nope") == []
    with pytest.raises(sqlite3.IntegrityError):  # a recording belongs to a stored session
        store.add_recording("unknown", tmp_path / "b.mcap", 40)
    store.db.execute("DROP TABLE recordings")  # as a file written before the table existed
    store.close()
    store = Store(db)
    assert store.recordings("s1") == []
    store.close()


def test_the_decision_model_resets_on_setup_and_go_only():
    model = DecisionModel()
    assert model.on_trial("setup", "consensus", "blue") and model.option == "blue"
    assert not model.on_trial("countdown", "dissensus", None) and model.mode == "consensus"
    assert model.on_trial("go", "dissensus", "red") and model.option is None
    assert model.accepts(5)
    model.on_hand(5, None)
    assert not model.accepts(5) and model.accepts(6)


def test_the_recorder_subscribes_to_the_rig_or_the_only_keys():
    from services.recording.record import key_exprs, one_line

    assert key_exprs(None, "rig2") == ["nod/rig2/**"]
    assert key_exprs(["vision/hand", "nod/rig9/safety/*"], "rig2") == [
        "nod/rig2/vision/hand", "nod/rig9/safety/*"]
    with pytest.raises(ValueError, match="not a key expression"):
        key_exprs(["vi*/hand"], "rig1")
    assert one_line("no router\n  at /root/x/orchestrator.rs:447.") == "no router"


def test_excluded_keys_are_matched_by_expression():
    from services.recording.record import Excluder

    excluded = Excluder(["nod/rig1/sim/camera", "nod/rig1/rig/*"])
    assert excluded("nod/rig1/sim/camera") and excluded("nod/rig1/rig/status")
    assert not excluded("nod/rig1/vision/hand") and not excluded("nod/rig2/sim/camera")
    assert excluded.count == 2
    assert not Excluder([])("nod/rig1/sim/camera")
