"""The wire contract: round trips, and strict rejection of everything a peer could get wrong."""

import contextlib
import math

import msgpack
import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.core import messages as m
from services.core.contract import TOPICS
from services.core.keys import Keys
from services.model.geometry import OptionsLayout

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


# --- schema 2: the messages of a table of N options

vectors = st.lists(st.floats(-1e6, 1e6), min_size=2, max_size=8).map(tuple)


@given(vectors, st.integers(0, 2**40))
def test_a_vector_round_trips_and_carries_version_2(values: tuple[float, ...], seq: int) -> None:
    msg = m.OptionVector(seq=seq, t_ns=5, values=values, src_seq=seq)
    payload = m.encode(msg)
    assert msgspec.msgpack.decode(payload)["v"] == 2
    assert m.decode(m.OptionVector, payload) == msg
    assert list(m.values_for(msg, len(values))) == list(values)


def test_an_old_payload_is_refused_in_one_line_on_either_side() -> None:
    old = msgspec.msgpack.encode({"v": 1, "seq": 1, "t_ns": 1, "values": [0.5, -0.5]})
    with pytest.raises(m.MessageError, match=r"^option_vector: schema version is not 2"):
        m.decode(m.OptionVector, old)
    new = m.encode(m.OptionVector(seq=1, t_ns=1, values=(0.5, -0.5)))
    with pytest.raises(m.MessageError, match=r"^scalar: schema version is not 1"):
        m.decode(m.Scalar, new)
    # the paper's messages are untouched: still version 1, byte for byte
    assert msgspec.msgpack.decode(m.encode(m.Scalar(seq=1, t_ns=1, value=0.5)))["v"] == 1


def test_a_vector_of_another_length_is_refused_with_how_to_fix_it() -> None:
    msg = m.OptionVector(seq=1, t_ns=1, values=(0.5, -0.25, -0.25))
    with pytest.raises(m.MessageError) as err:
        m.values_for(msg, 4)
    text = str(err.value)
    assert "\n" not in text and "3 values but this rig runs 4 options" in text
    assert "--options" in text
    for bad in ([0.5], [0.1] * 9, [0.5, float("nan")]):
        with pytest.raises(m.MessageError):
            m.decode(m.OptionVector, msgspec.msgpack.encode(
                {"v": 2, "seq": 1, "t_ns": 1, "values": bad}))


def test_an_index_outside_the_option_set_never_decodes() -> None:
    def press(option: int, n: int) -> bytes:
        return msgspec.msgpack.encode(
            {"v": 2, "seq": 1, "t_ns": 1, "n_options": n, "option": option, "trial": 1})

    assert m.decode(m.OptionsPress, press(2, 3)).option == 2
    with pytest.raises(m.MessageError, match="option 3 is not one of the 3 options"):
        m.decode(m.OptionsPress, press(3, 3))
    with pytest.raises(m.MessageError, match="n_options"):
        m.decode(m.OptionsPress, press(0, 9))
    result = m.OptionsResult(seq=1, t_ns=1, n_options=3, option=1, human=2, robot=0)
    assert m.decode(m.OptionsResult, m.encode(result)) == result
    with pytest.raises(m.MessageError, match="robot 4"):
        m.OptionsResult(seq=1, t_ns=1, n_options=4, robot=4)
    ev = m.OptionsTrialEvent(seq=1, t_ns=1, n_options=3, option=1)
    with pytest.raises(m.MessageError, match="for 3 options but this rig runs 4"):
        m.check_count(ev, 4)


def test_the_layout_carries_names_and_boxes() -> None:
    layout = OptionsLayout.row(3)
    msg = m.OptionsLayoutMsg(seq=1, t_ns=1, **m.layout_message_fields(("a", "b", "c"), layout))
    back = m.decode(m.OptionsLayoutMsg, m.encode(msg))
    assert back.layout().boxes == layout.boxes and back.names == ("a", "b", "c")
    with pytest.raises(m.MessageError, match="3 names but 2 boxes"):
        m.OptionsLayoutMsg(seq=1, t_ns=1, names=("a", "b", "c"), boxes=msg.boxes[:2])
    with pytest.raises(m.MessageError, match="4 boxes but this rig runs 3"):
        m.same_count(OptionsLayout.row(4), 3)


def test_the_option_keys_are_their_own() -> None:
    option_keys = {name for name in TOPICS if name.startswith("options/")}
    assert option_keys == {"options/layout", "options/z_h", "options/z_r", "options/b_r",
                           "options/arm_state", "options/press", "options/trial",
                           "options/result"}
    for name in option_keys:
        assert issubclass(TOPICS[name].message, m.OptionsMessage)
    for name in set(TOPICS) - option_keys:
        assert not issubclass(TOPICS[name].message, m.OptionsMessage), name
