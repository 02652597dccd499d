"""The N_o-option messages: vectors on keys of their own, schema version 2, strict decoding."""

from __future__ import annotations

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.core import messages as m
from services.core.contract import TOPICS
from services.model.geometry import OptionsLayout

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
