"""Each key's size limit bounds every valid message of its topic, and every session carries it."""

import json

import msgspec.inspect as mi
import pytest
import zenoh

from services.core import messages as m
from services.core.contract import TOPICS
from services.core.limits import low_pass_filters, max_payload_bytes, topic_limits
from services.core.session import MAX_MESSAGE_BYTES, make_config

WIDE = "\U0001f600"  # four bytes in UTF-8: the longest a character gets


def largest(t: mi.Type):
    """The value of type `t` with the longest encoding (strings of 4-byte characters…)."""
    if isinstance(t, mi.Metadata):
        return largest(t.type)
    if isinstance(t, mi.IntType):
        lo = t.ge if t.ge is not None else -(2**63)
        hi = t.le if t.le is not None else 2**63 - 1
        return lo if lo < -(2**31) else hi  # the widest msgpack form of the two ends
    if isinstance(t, mi.FloatType):
        return t.le if t.le is not None else 1.5
    if isinstance(t, mi.BoolType):
        return True
    if isinstance(t, mi.NoneType):
        return None
    if isinstance(t, mi.StrType):
        return ("a" * t.max_length) if t.max_length is not None else "a" * 64  # a pattern's 64
    if isinstance(t, mi.BytesType):
        return b"\xff\xd8\xff" + b"\x00" * (t.max_length - 3)  # a frame's JPEG marker first
    if isinstance(t, mi.LiteralType):
        return max(t.values, key=lambda v: len(str(v)))
    if isinstance(t, mi.UnionType):
        return max((largest(u) for u in t.types), key=lambda v: len(msgpack_of(v)))
    if isinstance(t, mi.TupleType):
        return tuple(largest(i) for i in t.item_types)
    if isinstance(t, mi.VarTupleType):
        return tuple(largest(t.item_type) for _ in range(t.max_length))
    if isinstance(t, mi.StructType):  # a nested record (a parameter's estimate)
        return t.cls(**{f.name: largest(f.type) for f in t.fields})
    raise AssertionError(f"no largest value for {t}")


def wide(t: mi.Type, value):
    """Free-text strings (no pattern, no literal) made of 4-byte characters."""
    if isinstance(t, mi.Metadata):
        return wide(t.type, value)
    if isinstance(t, mi.StrType) and t.pattern is None and t.max_length is not None:
        return WIDE * t.max_length
    if isinstance(t, mi.VarTupleType):
        return distinct(tuple(wide(t.item_type, v) for v in value))
    if isinstance(t, mi.StructType):
        import msgspec

        return msgspec.structs.replace(
            value, **{f.name: wide(f.type, getattr(value, f.name)) for f in t.fields})
    return value


def distinct(items: tuple) -> tuple:
    """A tuple of equal wide strings made distinct (an option set's names must be), each as long.

    The first stays as it was, so a field naming one of the set (O, a press) still names one.
    """
    if len(items) < 2 or not all(isinstance(s, str) and s and s[-1] == WIDE for s in items):
        return items
    return (items[0],) + tuple(s[:-1] + chr(ord(WIDE) + i) for i, s in enumerate(items[1:], 1))


def msgpack_of(value) -> bytes:
    import msgspec

    return msgspec.msgpack.encode(value)


def worst(cls: type[m.Message]) -> m.Message:
    info = mi.type_info(cls)
    kwargs = {f.name: wide(f.type, largest(f.type)) for f in info.fields}
    for name in ("option", "robot", "human"):  # must name one of the set: its widest name
        if isinstance(kwargs.get(name), str) and "options" in kwargs:
            kwargs[name] = kwargs["options"][0]
    return cls(**kwargs)


MESSAGES = sorted({t.message for t in TOPICS.values()}, key=lambda c: c.__name__)


@pytest.mark.parametrize("cls", MESSAGES, ids=lambda c: c.__name__)
def test_the_largest_valid_message_fits_its_limit_and_the_limit_is_not_loose(cls):
    msg = worst(cls)
    payload = m.encode(msg)
    assert m.decode(cls, payload) == msg  # valid: the decoder takes it whole
    limit = max_payload_bytes(cls)
    assert len(payload) <= limit
    # Loose only by the widest headers (5 bytes where the encoder needed 1-3) and numbers.
    assert limit <= 1.1 * len(payload) + 64, (len(payload), limit)


def test_a_60_kB_message_is_over_every_limit_but_the_camera_frames():
    limits = topic_limits()
    assert set(limits) == set(TOPICS)
    frames = {name for name, t in TOPICS.items() if t.message is m.VisionFrame}
    assert frames == {"vision/frame", "sim/camera"}
    assert all(size < 60_000 for name, size in limits.items() if name not in frames), limits
    assert all(m.MAX_BLOB_BYTES < limits[name] <= m.VisionFrame.MAX_BYTES for name in frames)
    assert max(limits.values()) < MAX_MESSAGE_BYTES


def test_every_key_of_the_contract_has_its_rule_and_the_rest_of_nod_the_largest():
    rules = low_pass_filters()
    by_key = {ke: r["size_limit"] for r in rules for ke in r["key_exprs"]}
    assert by_key.pop("nod/**") == max(topic_limits().values())
    assert by_key == {f"nod/*/{name}": size for name, size in topic_limits().items()}
    assert all(r["messages"] == ["put", "delete", "query", "reply"] for r in rules)


def rules_of(conf: zenoh.Config) -> list[dict]:
    """The low-pass rules of a config, without the fields zenoh fills in with null."""
    rules = json.loads(conf.get_json("low_pass_filter"))
    return [{k: v for k, v in rule.items() if v is not None} for rule in rules]


def test_every_session_config_carries_the_limits_and_no_shared_memory(tmp_path):
    for mode in ("client", "peer", "router"):
        conf = make_config(mode=mode)
        assert rules_of(conf) == low_pass_filters()
        assert conf.get_json("transport/shared_memory/enabled") == "false"
        zenoh.Config.from_json5(str(conf))  # a config zenoh itself accepts
    # On top of a file too (a lab's TLS and ACL config): its own rules are kept, first.
    own = {"messages": ["put"], "key_exprs": ["lab/**"], "size_limit": 10}
    path = tmp_path / "z.json5"
    path.write_text(json.dumps({"mode": "client", "low_pass_filter": [own],
                                "transport": {"shared_memory": {"enabled": True}}}))
    conf = make_config(config_file=path)
    assert rules_of(conf) == [own, *low_pass_filters()]
    assert conf.get_json("transport/shared_memory/enabled") == "false"


def test_the_lab_configs_carry_the_limits_themselves(tmp_path):
    # A stock `zenohd -c router.json5` (not only `nod router`) must refuse oversized messages and
    # keep shared memory off: the bounds are in the files `nod lab secure` writes.
    from services.lab.secure import secure

    written = secure(tmp_path, ["control", "arm"], "rig1", "127.0.0.1", 7447, 30,
                     tmp_path / "installed")
    configs = [p for p in written if p.name.endswith(".json5")]
    assert any(p.name == "router.json5" for p in configs) and len(configs) >= 3
    for path in configs:
        text = path.read_text()
        doc = json.loads(text[text.index("{"):])  # after the header comment
        assert doc["low_pass_filter"] == low_pass_filters(), path
        assert doc["transport"]["shared_memory"]["enabled"] is False, path
        zenoh.Config.from_file(str(path))  # and zenoh itself accepts the file
