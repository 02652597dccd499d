"""The wire contract: round trips, and strict rejection of everything a peer could get wrong.

One key space, schema 3: a message about options carries them (the paper's are red, blue); the
schema-1 payloads of recordings made before it are rewritten by `services.core.schema1`.
"""

import contextlib
import math
from pathlib import Path
from typing import Any

import msgpack
import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.core import messages as m
from services.core.contract import TOPICS
from services.core.keys import Keys, topic_of
from services.core.schema1 import OLD_VERSION, upgrade, version_of
from services.model.geometry import COLOURS, Box, OptionsLayout
from services.model.schedule import MAX_OPTIONS

GOLDEN = Path(__file__).resolve().parents[1] / "golden" / "session.mcap"  # a schema-1 recording

coord = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)
point = st.tuples(coord, coord)
PAPER = list(COLOURS)


def _raw(**fields):
    return msgpack.packb({"v": m.SCHEMA_VERSION, "seq": 1, "t_ns": 5, **fields})


@given(st.lists(point, min_size=1, max_size=21), st.integers(0, 2**62), st.integers(0, 2**62))
def test_hand_pose_round_trip(landmarks, seq, t_ns):
    cx = sum(p[0] for p in landmarks) / len(landmarks)
    cy = sum(p[1] for p in landmarks) / len(landmarks)
    msg = m.HandPose(seq=seq, t_ns=t_ns, detected=True, center=(cx, cy), landmarks=tuple(landmarks))
    assert m.decode(m.HandPose, m.encode(msg)) == msg


@given(st.binary(max_size=200))
def test_garbage_never_escapes_as_another_exception(payload):
    for cls in (m.HandPose, m.Opinions, m.Layout, m.TrialEvent, m.Estop, m.GazeMsg):
        with contextlib.suppress(m.MessageError):
            m.decode(cls, payload)


@given(
    st.dictionaries(
        st.text(max_size=8),
        st.one_of(
            st.none(),
            st.integers(-(2**63), 2**63 - 1),
            st.floats(),
            st.text(max_size=5),
            st.booleans(),
        ),
        max_size=6,
    )
)
def test_random_maps_decode_or_fail_cleanly(fields):
    payload = msgpack.packb({"v": m.SCHEMA_VERSION, **fields})
    try:
        msg = m.decode(m.Opinions, payload)
    except m.MessageError:
        return
    assert all(math.isfinite(v) for v in msg.values)


@pytest.mark.parametrize(
    ("payload", "fragment"),
    [
        (b"\xc1", "not valid msgpack"),
        (msgpack.packb([1, 2]), "Expected `object`, got `array`"),
        (msgpack.packb({"v": 99, "seq": 1, "t_ns": 1}), "schema version"),
        (msgpack.packb({"v": -1, "seq": 1, "t_ns": 1}), "schema version"),
        (msgpack.packb({"seq": 1, "t_ns": 1}), "schema version"),
        (msgpack.packb({"v": 1, "seq": 1, "t_ns": 1, "value": 0.5}), "schema version is not 3"),
        (msgpack.packb({"v": 2, "seq": 1, "t_ns": 1, "values": [0.5, -0.5]}),
         "schema version is not 3"),
        (_raw(options=PAPER, values=[float("nan"), 0.0]),
         r"Expected `float` >= .* at `\$.values\[0\]`"),
        (_raw(options=PAPER, values=[0.0, float("inf")]),
         r"Expected `float` <= .* at `\$.values\[1\]`"),
        (_raw(options=PAPER, values=["3", 0.0]), "Expected `float`, got `str`"),
        (_raw(options=PAPER, values=[True, 0.0]), "Expected `float`, got `bool`"),
        (_raw(options=PAPER, values=[0.5, -0.5], src_seq=-1),
         r"Expected `int` >= 0 - at `\$.src_seq`"),
        (_raw(options=PAPER, values=[0.5, -0.5], extra=2), "unknown field `extra`"),
        (_raw(values=[0.5, -0.5]), "missing required field `options`"),
        (_raw(options=PAPER), "missing required field `values`"),
        (_raw(options=PAPER, values=[0.5]), "length >= 2"),
        (_raw(options=["red"], values=[0.5, -0.5]), "length >= 2"),
        (_raw(options=PAPER, values=[0.1] * 9), "length <= 8"),
        (_raw(options=PAPER, values=[0.5, -0.25, -0.25]), "3 values for 2 options"),
        (_raw(options=["red", ""], values=[0.5, -0.5]), "length >= 1"),
        (msgpack.packb({"v": 3, "t_ns": 5, "options": PAPER, "values": [0.5, -0.5]}),
         "missing required field `seq`"),
    ],
)
def test_bad_opinions_are_rejected_with_a_reason_in_one_line(payload, fragment):
    with pytest.raises(m.MessageError, match=fragment) as err:
        m.decode(m.Opinions, payload)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("fields", "fragment"),
    [
        ({"detected": True, "center": [0.5, 0.5], "landmarks": []}, "at least one landmark"),
        ({"detected": False, "center": [0.5, 0.5], "landmarks": []}, "no center"),
        ({"detected": True, "center": [0.5], "landmarks": [[0.5, 0.5]]}, "length 2, got 1"),
        ({"detected": True, "center": [0.5, 0.5], "landmarks": [[0.5, 9.0]]}, r"\[0\]\[1\]"),
        ({"detected": True, "center": [0.5, 0.5], "landmarks": [[0.5, 0.5]] * 65}, "<= 64"),
        ({"detected": True, "center": [0.5, 0.5], "landmarks": [[True, 0.5]]}, "got `bool`"),
        ({"detected": "yes"}, "Expected `bool`, got `str`"),
    ],
)
def test_bad_hand_poses_are_rejected(fields, fragment):
    with pytest.raises(m.MessageError, match=fragment):
        m.decode(m.HandPose, _raw(**fields))


def test_literal_fields_are_checked():
    with pytest.raises(m.MessageError, match="Invalid enum value 'dance'"):
        m.decode(m.TrialEvent, _raw(options=PAPER, phase="dance"))


def test_keys_are_scoped_by_rig_and_map_back_to_types():
    keys = Keys("labA")
    for topic, t in TOPICS.items():
        key = keys.topic(topic)
        assert key == f"nod/labA/{topic}"
        assert keys.message_type(key) is t.message
    assert keys.message_type("nod/other/vision/hand") is None
    with pytest.raises(ValueError, match="rig name"):
        Keys("bad/rig")


MESSAGE_TYPES = sorted({t.message for t in TOPICS.values()}, key=lambda c: c.KIND)
junk = st.recursive(
    st.one_of(
        st.none(), st.booleans(), st.integers(-(2**64), 2**64), st.floats(),
        st.text(max_size=20), st.binary(max_size=20),
    ),
    lambda inner: st.one_of(
        st.lists(inner, max_size=5), st.dictionaries(st.text(max_size=8), inner, max_size=5)
    ),
    max_leaves=30,
)


@pytest.mark.parametrize("cls", MESSAGE_TYPES, ids=lambda c: c.KIND)
@given(payload=st.binary(max_size=400))
def test_raw_bytes_on_every_key_decode_or_fail_cleanly(cls, payload):
    with contextlib.suppress(m.MessageError):
        m.decode(cls, payload)


@pytest.mark.parametrize("cls", MESSAGE_TYPES, ids=lambda c: c.KIND)
@given(fields=st.dictionaries(st.sampled_from(["v", "seq", "t_ns", "x"]), junk, max_size=4)
       | st.builds(dict, junk.filter(lambda x: isinstance(x, dict))))
def test_structured_junk_on_every_key_decodes_to_a_valid_message_or_fails_cleanly(cls, fields):
    fields = {**fields}
    for name in m.fields(cls)[2:]:  # poison the message's own fields too, now and then
        if len(fields) % 3 == 0:
            fields[name] = fields.get("x")
    try:
        msg = m.decode(cls, msgpack.packb(fields, use_bin_type=True))
    except m.MessageError:
        return
    except (OverflowError, ValueError, TypeError):  # msgpack itself could not encode the junk
        return
    assert type(msg) is cls
    for name in m.fields(cls):  # whatever passed is finite and within its bounds
        value = getattr(msg, name)
        if isinstance(value, float):
            assert math.isfinite(value)


# --- schema 3: one key space, every message about options carries them ---------------------

opinion = st.floats(-1e6, 1e6, allow_nan=False)
name = st.text(st.characters(min_codepoint=33, max_codepoint=0x2FF), min_size=1, max_size=32)
option_sets = st.lists(name, min_size=2, max_size=MAX_OPTIONS, unique=True).map(tuple)


@st.composite
def boxes_for(draw, n: int) -> tuple[tuple[float, float, float, float], ...]:
    out = []
    for _ in range(n):
        x1, x2 = sorted((draw(coord), draw(coord)))
        y1, y2 = sorted((draw(coord), draw(coord)))
        out.append((x1, y1, x2, y2))
    return tuple(out)


def _one_line(err: pytest.ExceptionInfo[BaseException]) -> str:
    text = str(err.value)
    assert text and "\n" not in text, text
    return text


@given(st.data(), option_sets, st.integers(0, 2**62))
def test_opinions_round_trip_over_any_option_set(data, options, seq):
    values = data.draw(st.lists(opinion, min_size=len(options), max_size=len(options)))
    msg = m.Opinions(seq=seq, t_ns=5, options=options, values=tuple(values), src_seq=seq)
    payload = m.encode(msg)
    assert msgspec.msgpack.decode(payload)["v"] == m.SCHEMA_VERSION == 3
    assert m.decode(m.Opinions, payload) == msg
    assert list(msg.vector(options)) == values
    theta = data.draw(st.none() | st.floats(0.0, math.pi))
    observed = m.Observed(seq=seq, t_ns=5, options=options, values=tuple(values), theta=theta)
    assert m.decode(m.Observed, m.encode(observed)) == observed


@given(st.data(), option_sets, st.floats(0.0, 1.0))
def test_a_layout_round_trips_and_its_boxes_are_its_options(data, options, commit_y):
    boxes = data.draw(boxes_for(len(options)))
    msg = m.Layout(seq=1, t_ns=2, options=options, boxes=boxes, commit_y=commit_y)
    back = m.decode(m.Layout, m.encode(msg))
    assert back == msg
    assert back.table().boxes == tuple(Box(*b) for b in boxes)
    assert back.table().commit.y == commit_y
    if len(options) == 2:  # the paper's kernel reads option 0 as red, option 1 as blue
        assert (back.paper_table().red, back.paper_table().blue) == (Box(*boxes[0]),
                                                                     Box(*boxes[1]))
    else:
        with pytest.raises(m.MessageError, match="not the paper's two") as err:
            back.paper_table()
        _one_line(err)


@given(st.data(), option_sets)
def test_trial_events_and_results_round_trip_naming_their_options(data, options):
    some = st.none() | st.sampled_from(options)
    ev = m.TrialEvent(seq=1, t_ns=2, options=options, phase=data.draw(st.sampled_from(
        ["setup", "countdown", "go", "end", "result", "abort"])), trial=data.draw(
        st.integers(0, 10_000)), mode=data.draw(st.sampled_from(["consensus", "dissensus"])),
        option=data.draw(some), text="low", session="S1")
    assert m.decode(m.TrialEvent, m.encode(ev)) == ev
    res = m.TrialResult(seq=1, t_ns=2, options=options, trial=3, option=data.draw(some),
                        robot=data.draw(some), human=data.draw(some), outcome="D", score=-1,
                        interrupted=data.draw(st.booleans()))
    assert m.decode(m.TrialResult, m.encode(res)) == res


@given(option_sets, st.integers(1, 3))
def test_values_or_boxes_of_another_count_than_the_options_are_refused_in_one_line(options, d):
    n = len(options)
    for count in (n - d, n + d):
        if not 2 <= count <= MAX_OPTIONS:
            continue
        with pytest.raises(m.MessageError, match=f"{count} values for {n} options") as err:
            m.Opinions(seq=1, t_ns=1, options=options, values=(0.0,) * count)
        _one_line(err)
        raw = _raw(options=list(options), values=[0.0] * count)
        with pytest.raises(m.MessageError, match=f"{count} values for {n} options") as err:
            m.decode(m.Opinions, raw)
        _one_line(err)
        boxes = [[0.1, 0.1, 0.2, 0.2]] * count
        with pytest.raises(m.MessageError, match=f"{n} options but {count} boxes") as err:
            m.decode(m.Layout, _raw(options=list(options), boxes=boxes))
        _one_line(err)


@given(option_sets, name)
def test_an_option_none_of_the_messages_options_is_refused_in_one_line(options, other):
    if other in options:
        return
    for field in ("option",):
        raw = _raw(options=list(options), phase="setup", **{field: other})
        with pytest.raises(m.MessageError, match=f"{field} .* is none of its options") as err:
            m.decode(m.TrialEvent, raw)
        _one_line(err)
    for field in ("option", "robot", "human"):
        with pytest.raises(m.MessageError, match=f"{field} .* is none of its options") as err:
            m.decode(m.TrialResult, _raw(options=list(options), **{field: other}))
        _one_line(err)
    with pytest.raises(m.MessageError, match="is none of this rig's") as err:
        m.index_in(options, other, "press")
    _one_line(err)
    assert [m.index_in(options, o) for o in options] == list(range(len(options)))


def test_an_option_set_must_name_distinct_options():
    for cls, extra in ((m.Layout, {"boxes": [[0.1, 0.1, 0.2, 0.2]] * 2}),
                       (m.TrialEvent, {}), (m.TrialResult, {})):
        with pytest.raises(m.MessageError, match="distinct") as err:
            m.decode(cls, _raw(options=["red", "red"], **extra))
        _one_line(err)
    with pytest.raises(m.MessageError, match="the blue box needs x1 <= x2"):
        m.Layout(seq=1, t_ns=1, options=COLOURS, boxes=((0.1, 0.1, 0.2, 0.2),
                                                        (0.5, 0.1, 0.4, 0.2)))


@given(opinion)
def test_the_papers_signed_opinion_decodes_exactly(z):
    for cls in (m.Opinions, m.Observed):
        msg = m.decode(cls, m.encode(cls(seq=1, t_ns=1, **m.signed_fields(z))))
        assert msg.signed == z and msg.values == (z, -z) and msg.options == COLOURS
        assert math.copysign(1.0, msg.signed) == math.copysign(1.0, z)  # even a -0.0


def test_a_signed_opinion_is_the_two_option_case_only():
    three = m.Opinions(seq=1, t_ns=1, options=("a", "b", "c"), values=(0.5, -0.25, -0.25))
    with pytest.raises(m.MessageError, match="3 options have no signed opinion") as err:
        _ = three.signed
    _one_line(err)
    with pytest.raises(ValueError, match="two options, not 3"):
        m.signed_fields(0.5, ("a", "b", "c"))
    assert m.signed_fields(0.5, ("left", "right")) == {"options": ("left", "right"),
                                                       "values": (0.5, -0.5)}


def test_a_message_for_another_option_set_is_refused_with_how_to_fix_it():
    msg = m.Opinions(seq=1, t_ns=1, options=("a", "b", "c"), values=(0.5, -0.25, -0.25))
    for ours in (("a", "b", "c", "d"), ("a", "c", "b"), COLOURS):
        with pytest.raises(m.MessageError, match="this rig runs") as err:
            msg.vector(ours)
        assert "--options" in _one_line(err)
    ev = m.TrialEvent(seq=1, t_ns=1, options=COLOURS, option="red")
    with pytest.raises(m.MessageError, match="for options red,blue but this rig runs a,b,c"):
        m.check_options(ev, ("a", "b", "c"))
    m.check_options(ev, COLOURS)  # ours: no complaint


def test_layout_fields_build_a_layout_from_either_geometry():
    row = OptionsLayout.row(3)
    msg = m.Layout(seq=1, t_ns=1, **m.layout_fields(("a", "b", "c"), row))
    assert msg.table() == row
    paper = OptionsLayout.row(2)
    two = m.Layout(seq=1, t_ns=1, **m.layout_fields(COLOURS, paper))
    again = m.Layout(seq=1, t_ns=1, **m.layout_fields(COLOURS, two.paper_table()))
    assert again == two
    with pytest.raises(ValueError, match="2 option names for 3 boxes"):
        m.layout_fields(COLOURS, row)


def test_one_key_space_no_options_keys_and_every_message_of_schema_3():
    assert not [name for name in TOPICS if name.startswith("options/")]
    for t in TOPICS.values():
        assert m.schema_version(t.message) == 3, t.name
    for gone in ("Scalar", "OptionVector", "OptionsLayoutMsg", "OptionsArmState",
                 "OptionsPress", "OptionsTrialEvent", "OptionsResult", "values_for",
                 "check_count", "same_count", "layout_from_msg", "Colour"):
        assert not hasattr(m, gone), gone


# --- schema 1: recordings made before one key space are rewritten, then decoded as today's ----


def _v1(**fields: Any) -> bytes:
    return msgpack.packb({"v": OLD_VERSION, "seq": 4, "t_ns": 9, **fields})


def _decoded(topic: str, payload: bytes) -> Any:
    return m.decode(TOPICS[topic].message, upgrade(topic, payload))


RED_BOX, BLUE_BOX = [0.72, 0.12, 0.86, 0.26], [0.14, 0.12, 0.28, 0.26]


def test_a_schema_1_layout_becomes_the_two_option_table_it_described():
    msg = _decoded("vision/layout", _v1(red=RED_BOX, blue=BLUE_BOX, commit_y=0.4))
    assert (msg.seq, msg.t_ns, msg.options, msg.commit_y) == (4, 9, COLOURS, 0.4)
    assert msg.paper_table().red == Box(*RED_BOX) and msg.paper_table().blue == Box(*BLUE_BOX)


@pytest.mark.parametrize("topic", ["decision/z_r", "decision/b_r"])
@given(z=opinion)
def test_a_schema_1_scalar_becomes_the_signed_opinion_exactly(topic, z):
    msg = _decoded(topic, _v1(value=z, src_seq=3))
    assert msg.signed == z and msg.values == (z, -z) and msg.options == COLOURS
    assert msg.src_seq == 3


def test_a_schema_1_observed_keeps_what_it_was_read_from():
    msg = _decoded("decision/z_h", _v1(value=-0.25, src_seq=7, theta=1.5, distance=0.2))
    assert isinstance(msg, m.Observed)
    assert (msg.signed, msg.src_seq, msg.theta, msg.distance) == (-0.25, 7, 1.5, 0.2)
    unset = _decoded("decision/z_h", _v1(value=0.0, src_seq=8, theta=None, distance=None))
    assert unset.theta is None and unset.distance is None and unset.values == (0.0, -0.0)


def test_schema_1_presses_events_and_results_name_the_same_options():
    press = _decoded("actuation/press", _v1(colour="blue", trial=2))
    assert (press.option, press.trial) == ("blue", 2)
    ev = _decoded("experiment/trial", _v1(phase="setup", trial=1, mode="consensus",
                                          option="red", text="low", session="S1"))
    assert (ev.options, ev.phase, ev.trial, ev.mode, ev.option, ev.text, ev.session) == (
        COLOURS, "setup", 1, "consensus", "red", "low", "S1")
    res = _decoded("experiment/result", _v1(
        trial=1, mode="dissensus", option=None, robot="blue", human="red", outcome="D",
        switches=1, violations=0, score=0, session="S1", interrupted=False))
    assert (res.options, res.option, res.robot, res.human, res.outcome, res.switches) == (
        COLOURS, None, "blue", "red", "D", 1)
    arm = _decoded("actuation/state", _v1(ee=[0.5, 0.08], phase="press", target="red"))
    assert arm.target == "red" and arm.phase == "press"  # a colour is the option's name


def test_a_schema_3_payload_and_anything_not_schema_1_pass_unchanged():
    payloads = {
        "decision/z_r": m.encode(m.Opinions(seq=1, t_ns=1, **m.signed_fields(0.5))),
        "vision/layout": m.encode(m.Layout(seq=1, t_ns=1, **m.layout_fields(
            ("a", "b", "c"), OptionsLayout.row(3)))),
        "actuation/press": m.encode(m.PressMsg(seq=1, t_ns=1, option="green", trial=1)),
        "experiment/trial": m.encode(m.TrialEvent(seq=1, t_ns=1, options=COLOURS)),
        "rig/status": m.encode(m.NodeStatus(seq=1, t_ns=1)),
    }
    for topic, payload in payloads.items():
        assert upgrade(topic, payload) is payload
        assert version_of(payload) == 3
    for junk in (b"", b"\xc1", msgpack.packb([1, 2]), msgpack.packb({"v": 2, "values": [1]})):
        assert upgrade("decision/z_r", junk) is junk


@pytest.mark.parametrize(("topic", "payload", "fragment"), [
    ("decision/z_r", _v1(value="abc", src_seq=1), "Expected `float`, got `str`"),
    ("decision/z_r", _v1(value=True, src_seq=1), "Expected `float`, got `bool`"),
    ("decision/z_r", _v1(value=float("nan"), src_seq=1), r"Expected `float` >="),
    ("decision/z_r", _v1(value=0.5, src_seq=1, extra=1), "unknown field `extra`"),
    ("decision/z_h", _v1(value=0.5, theta=9.0), r"Expected `float` <="),
    ("vision/layout", _v1(red=RED_BOX), r"Expected `array`, got `None` - at `\$.boxes\[1\]`"),
    ("vision/layout", _v1(red=RED_BOX, blue=[0.3, 0.1, 0.2, 0.2]), "blue box needs x1 <= x2"),
    ("actuation/press", _v1(colour=5, trial=1), "Expected `str`, got `int`"),
    ("experiment/trial", _v1(phase="setup", option="green"), "option 'green' is none of"),
    ("experiment/result", _v1(robot="purple"), "robot 'purple' is none of"),
    ("experiment/result", _v1(outcome="X"), "Invalid enum value 'X'"),
], ids=lambda x: x if isinstance(x, str) and "/" in x else "")
def test_a_schema_1_payload_that_was_garbage_is_refused_as_garbage(topic, payload, fragment):
    with pytest.raises(m.MessageError, match=fragment) as err:
        _decoded(topic, payload)
    _one_line(err)


@pytest.mark.parametrize("topic", sorted(TOPICS))
@given(fields=st.dictionaries(st.sampled_from(
    ["seq", "t_ns", "value", "red", "blue", "colour", "option", "robot", "values", "options"]),
    junk, max_size=5))
def test_any_schema_1_map_upgrades_to_a_valid_message_or_fails_cleanly(topic, fields):
    try:
        payload = msgpack.packb({"v": OLD_VERSION, **fields}, use_bin_type=True)
    except (OverflowError, ValueError, TypeError):
        return
    with contextlib.suppress(m.MessageError):
        msg = _decoded(topic, payload)
        assert type(msg) is TOPICS[topic].message


def _same_thing(topic: str, old: dict[str, Any], new: m.Message) -> None:
    """The schema-3 message says what the schema-1 map said, field by field."""
    renamed = {"colour": "option"}
    for key, value in old.items():
        if key == "v":
            continue
        if key == "value":
            assert isinstance(new, m.Opinions) and new.signed == value
            assert new.options == COLOURS
        elif key in ("red", "blue"):
            assert isinstance(new, m.Layout)
            assert list(new.boxes[COLOURS.index(key)]) == value
        else:
            got = msgspec.msgpack.decode(msgspec.msgpack.encode(getattr(new, renamed.get(key,
                                                                                      key))))
            assert got == value, (topic, key)
    if isinstance(new, m.TrialEvent | m.TrialResult):
        assert new.options == COLOURS


def test_every_payload_of_a_schema_1_recording_upgrades_to_the_same_message():
    """The golden session (recorded before one key space): every payload, every key."""
    from mcap.reader import make_reader

    seen: dict[str, int] = {}
    with GOLDEN.open("rb") as fh:
        for _, channel, message in make_reader(fh).iter_messages():
            topic = topic_of(channel.topic)
            assert topic is not None, channel.topic
            old = msgspec.msgpack.decode(message.data)
            assert old["v"] == OLD_VERSION
            new = _decoded(topic, message.data)
            _same_thing(topic, old, new)
            seen[topic] = seen.get(topic, 0) + 1
    assert {"vision/layout", "decision/z_h", "decision/z_r", "decision/b_r", "actuation/press",
            "experiment/trial", "experiment/result"} <= set(seen)
