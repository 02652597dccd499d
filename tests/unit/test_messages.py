"""The wire contract: round trips, and strict rejection of everything a peer could get wrong."""

import contextlib
import math

import msgpack
import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.core import messages as m
from services.core.contract import TOPICS
from services.core.keys import Keys

coord = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)
point = st.tuples(coord, coord)


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
    for cls in (m.HandPose, m.Scalar, m.TrialEvent, m.Estop, m.GazeMsg):
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
        msg = m.decode(m.Scalar, payload)
    except m.MessageError:
        return
    assert math.isfinite(msg.value)


@pytest.mark.parametrize(
    ("payload", "fragment"),
    [
        (b"\xc1", "not valid msgpack"),
        (msgpack.packb([1, 2]), "Expected `object`, got `array`"),
        (msgpack.packb({"v": 99, "seq": 1, "t_ns": 1}), "schema version"),
        (msgpack.packb({"v": -1, "seq": 1, "t_ns": 1}), "schema version"),
        (msgpack.packb({"seq": 1, "t_ns": 1}), "schema version"),
        (_raw(value=float("nan"), src_seq=1), r"Expected `float` >= .* at `\$.value`"),
        (_raw(value=float("inf"), src_seq=1), r"Expected `float` <= .* at `\$.value`"),
        (_raw(value="3", src_seq=1), "Expected `float`, got `str`"),
        (_raw(value=True, src_seq=1), "Expected `float`, got `bool`"),
        (_raw(value=1.0, src_seq=-1), r"Expected `int` >= 0 - at `\$.src_seq`"),
        (_raw(value=1.0, src_seq=1, extra=2), "unknown field `extra`"),
        (msgpack.packb({"v": 1, "t_ns": 5, "value": 1.0}), "missing required field `seq`"),
    ],
)
def test_bad_scalars_are_rejected_with_a_reason(payload, fragment):
    with pytest.raises(m.MessageError, match=fragment):
        m.decode(m.Scalar, payload)


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
        m.decode(m.TrialEvent, _raw(phase="dance"))


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
