"""Recordings any reader opens: every channel decodes with the schema it declares (checked with
mcap's own reader and a standard JSON Schema validator, not our decoder), an older recording
still replays and converts, `nod record convert` round-trips, and the viewers' layouts are
attached.
"""

from __future__ import annotations

import base64
import hashlib
import json
import re
from pathlib import Path

import jsonschema
import msgspec
from mcap.reader import make_reader
from rerun.chunk import RrdReader

from services.core import messages as m
from services.core.keys import topic_of
from services.recording.attachments import FOXGLOVE_LAYOUT, RERUN_BLUEPRINT, attach_views
from services.recording.convert import CONVERTED_METADATA, convert, main
from services.recording.mcap_io import FILE_METADATA, McapIn, McapOut
from services.recording.record import Recorder
from services.recording.selection import decode_entry
from services.recording.through import through_decision
from services.views.entities import APPLICATION_ID, ENTITIES

GOLDEN = Path(__file__).parents[1] / "golden" / "session.mcap"  # msgpack, schema 1
JPEG = b"\xff\xd8\xff\xe0" + bytes(range(256)) * 4


def _record_session(path: Path) -> list[tuple[str, bytes]]:
    """The golden session's traffic (and a camera frame) through the recorder; what it got."""
    out = McapOut(path)
    out.metadata(FILE_METADATA, {"rig": "rig1"})
    attach_views(out, "rig1", 1)
    rec = Recorder(out)
    sent = [(e.key, e.payload, e.message.log_time) for e in McapIn(GOLDEN) if e.valid]
    frame = m.VisionFrame(seq=1, t_ns=5, jpeg=JPEG, width=320, height=240, detected=True)
    sent.append(("nod/rig1/vision/frame", m.encode(frame), sent[-1][2] + 1))
    sent.append(("nod/rig1/vision/hand", b"\xc1not msgpack", sent[-1][2] + 2))
    for key, payload, log_time in sent:
        rec.add(key, payload, log_time)
    out.finish()
    assert sum(rec.invalid.values()) == 1
    return [(k, p) for k, p, _ in sent[:-1]]


def test_every_channel_decodes_with_the_schema_it_declares_by_standard_readers(tmp_path):
    path = tmp_path / "session.mcap"
    sent = _record_session(path)
    seen: dict[str, int] = {}
    got: list[tuple[str, bytes]] = []
    validators: dict[int, jsonschema.Draft202012Validator] = {}
    with path.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None
        for schema, channel, message in reader.iter_messages():
            if "invalid" in channel.metadata:  # the forged payload, kept apart, no schema
                assert (schema, channel.message_encoding) == (None, "application/octet-stream")
                continue
            assert schema is not None and schema.encoding == "jsonschema"
            assert channel.message_encoding == "json"
            if schema.id not in validators:
                declared = json.loads(schema.data)
                jsonschema.Draft202012Validator.check_schema(declared)
                assert declared["title"] == schema.name == channel.metadata["message"]
                validators[schema.id] = jsonschema.Draft202012Validator(declared)
            body = json.loads(message.data)
            validators[schema.id].validate(body)
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
            got.append((channel.topic, body))
    # every message arrived whole: the JSON is the travelled payload, field for field
    assert len(got) == len(sent)
    for (key, payload), (topic, body) in zip(sent, got, strict=True):
        expected = msgspec.msgpack.decode(payload)
        if "jpeg" in expected:  # bytes: base64, as the schema says (contentEncoding)
            assert declared_encoding(path, topic) == "base64"
            assert base64.b64decode(body["jpeg"]) == expected["jpeg"] == JPEG
            expected["jpeg"] = body["jpeg"]
        assert (topic, body) == (key, json.loads(json.dumps(expected)))
    assert len(seen) == 15 and seen["nod/rig1/vision/hand"] > 800


def declared_encoding(path: Path, topic: str) -> str:
    """The contentEncoding the JSON Schema of `topic`'s channel declares for `jpeg`."""
    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    (channel,) = [c for c in summary.channels.values() if c.topic == topic and c.schema_id]
    return json.loads(summary.schemas[channel.schema_id].data)["properties"]["jpeg"][
        "contentEncoding"]


def test_readers_get_msgpack_payloads_of_todays_schema_from_json_channels(tmp_path):
    path = tmp_path / "session.mcap"
    sent = _record_session(path)
    read = [(e.key, msgspec.msgpack.decode(e.payload)) for e in McapIn(path) if e.valid]
    # what replay, --follow, selection and through publish or decode (the fields' order aside)
    assert read == [(k, msgspec.msgpack.decode(p)) for k, p in sent]
    edited = tmp_path / "edited.mcap"
    out = McapOut(edited)
    out.write(out.channel("nod/rig1/vision/hand"), 1, 1, b'{"v": 3, "seq": -1, "t_ns": 0}')
    out.finish()
    (e,) = McapIn(edited)
    assert e.payload == b'{"v": 3, "seq": -1, "t_ns": 0}'  # refused downstream, as any garbage
    assert decode_entry("vision/hand", e) is None


def test_an_older_recording_converts_and_replays_the_same(tmp_path):
    new = tmp_path / "new.mcap"
    res = convert(GOLDEN, new)
    assert res.encodings == ("msgpack",) and res.versions == (1,) and res.truncated is None
    old_entries, new_entries = list(McapIn(GOLDEN)), list(McapIn(new))
    assert res.messages == len(old_entries) == len(new_entries)
    for a, b in zip(old_entries, new_entries, strict=True):
        assert (a.key, msgspec.msgpack.decode(a.payload), a.message.log_time,
                a.message.publish_time) == (b.key, msgspec.msgpack.decode(b.payload),
                                            b.message.log_time, b.message.publish_time)
        assert b.channel.message_encoding == "json"
        assert json.loads(b.message.data)["v"] == m.SCHEMA_VERSION
    with new.open("rb") as fh:
        reader = make_reader(fh)
        meta = [(r.name, r.metadata) for r in reader.iter_metadata()]
        names = [a.name for a in reader.iter_attachments()]
    old_meta = McapIn(GOLDEN)
    list(old_meta)
    assert meta[:-1] == old_meta.metadata  # every record kept, in order
    name, converted = meta[-1]
    assert name == CONVERTED_METADATA
    assert converted["from_sha256"] == hashlib.sha256(GOLDEN.read_bytes()).hexdigest()
    assert converted["from_file"] == str(GOLDEN)
    assert (converted["from_message_encodings"], converted["from_schema_versions"]) == (
        "msgpack", "1")
    assert names == [FOXGLOVE_LAYOUT, RERUN_BLUEPRINT]
    # the decision engine re-run over the converted file says what it said over the original
    a = through_decision(GOLDEN, tmp_path / "a.mcap", None)
    b = through_decision(new, tmp_path / "b.mcap", None)
    assert [t.final() for t in a.trials] == [t.final() for t in b.trials] and a.trials
    assert (a.poses, a.recomputed) == (b.poses, b.recomputed)


def test_nod_record_convert_round_trips(tmp_path, capsys):
    once, twice = tmp_path / "once.mcap", tmp_path / "twice.mcap"
    assert main([str(GOLDEN), str(once)]) == 0
    assert "7513 messages as JSON in schema 3 (from msgpack, schema 1)" in capsys.readouterr().out
    assert main([str(once), str(twice)]) == 0
    assert "(from json, schema 3)" in capsys.readouterr().out
    first, second = list(McapIn(once)), list(McapIn(twice))
    assert [(e.key, e.message.data, e.message.log_time) for e in first] == [
        (e.key, e.message.data, e.message.log_time) for e in second]
    again = McapIn(twice)
    list(again)
    assert [n for n, _ in again.metadata].count(CONVERTED_METADATA) == 2
    assert main([str(once), str(once)]) == 2
    assert "NEW must not be OLD" in capsys.readouterr().err


def test_the_layout_and_the_blueprint_show_the_hand_the_opinions_and_the_arm(tmp_path):
    path = tmp_path / "session.mcap"
    _record_session(path)
    with path.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        attachments = {a.name: a for a in reader.iter_attachments()}
    assert summary is not None
    schemas = {c.topic: json.loads(summary.schemas[c.schema_id].data)
               for c in summary.channels.values() if c.schema_id}
    layout = json.loads(attachments[FOXGLOVE_LAYOUT].data)
    paths = [p["value"] for panel in layout["configById"].values() for p in panel.get("paths", [])]
    fields = set()
    for p in paths:  # every path names a recorded topic and a field its schema has
        topic, field = re.fullmatch(r'"([^"]+)"\.(\w+)(\[\d\])?', p).group(1, 2)
        assert field in schemas[topic]["properties"], p
        fields.add((topic_of(topic), field))
    assert {("vision/hand", "center"), ("actuation/state", "ee"), ("decision/z_r", "values"),
            ("decision/z_h", "values"), ("decision/b_r", "values")} <= fields
    rbl = tmp_path / "trial.rbl"
    rbl.write_bytes(attachments[RERUN_BLUEPRINT].data)
    assert attachments[RERUN_BLUEPRINT].media_type == "application/vnd.rerun.blueprint"
    (blueprint,) = RrdReader(rbl).blueprints()  # the SDK reads it back
    assert blueprint.application_id == APPLICATION_ID
    assert {"opinion/z_r", "table/hand", "table/arm"} <= set(ENTITIES.values())


def test_the_monitor_shows_a_recording_under_the_blueprints_entities(tmp_path, capsys):
    from services.monitor.bridge import rrd_rows
    from services.monitor.service import main as monitor
    from services.views.blueprint import trial_blueprint

    path, rrd = tmp_path / "session.mcap", tmp_path / "session.rrd"
    convert(GOLDEN, path)
    assert monitor(["--from", str(path), "--save", str(rrd)]) == 0
    assert "messages shown, 0 undecodable" in capsys.readouterr().out
    temporal, _ = rrd_rows(rrd)
    z_r = sum(1 for e in McapIn(path) if topic_of(e.key) == "decision/z_r")
    assert temporal["/opinion/z_r"] == z_r > 800
    assert temporal["/table/hand"] > 800 and temporal["/table/arm"] > 800
    # every view of the attached blueprint has entities of the recording under its origin
    origins = [str(v.origin) for v in _views(trial_blueprint().root_container)]
    assert set(origins) == {"opinion", "state", "table", "log"}
    for origin in origins:
        assert any(e.startswith(f"/{origin}/") for e in temporal), origin


def _views(node):
    """The views under a blueprint container, depth first."""
    views = []
    for child in getattr(node, "contents", []) or []:
        views.extend(_views(child))
    if hasattr(node, "origin"):
        views.append(node)
    return views
