"""Size limits of the rig's keys, derived from the contract: each topic's largest honest payload.

`max_payload_bytes(cls)` is an upper bound on the msgpack encoding of any valid message of type
`cls`, computed from its schema (every field's type and its `max_length`, in msgspec's own
description of the type): each number at 9 bytes, each string at 4 bytes a character plus a
5-byte header, each collection at its longest, every map key written out. A type the schema
leaves unbounded falls back on the message's `MAX_BYTES`, so the bound is never looser than the
decoder's. Adding a field to a message moves its bound with it.

`low_pass_filters()` turns the bounds into zenoh's `low_pass_filter` rules, one per key of the
contract on every rig (`nod/*/<topic>`) and one for any other key under `nod/`: the router and
every session drop a bigger put, delete, query or reply before routing it or handing it to
Python. `Node.subscribe` checks the same bound again (a peer with another config).
"""

from __future__ import annotations

import re
from functools import cache

import msgspec.inspect as mi

from services.core import messages as m
from services.core.contract import TOPICS

NUMBER = 9  # msgpack int64/uint64/float64: a marker byte and 8 bytes (the widest form)
HEADER = 5  # str32/bin32/array32/map32 marker and length (the widest form)
UTF8 = 4  # bytes a character may take
# A pattern that bounds a string's length ("^[A-Za-z0-9_.-]{1,64}$" has at most 64 characters).
_BOUNDED_PATTERN = re.compile(r"\^\[[^\]]*\]\{\d+,(\d+)\}\$")
_MESSAGES = ["put", "delete", "query", "reply"]


def _str_bound(max_length: int | None, pattern: str | None) -> int | None:
    if max_length is None and pattern is not None:
        match = _BOUNDED_PATTERN.fullmatch(pattern)
        if match:
            max_length = int(match.group(1))
    return None if max_length is None else HEADER + UTF8 * max_length


def _sum(bounds: list[int | None]) -> int | None:
    return None if any(b is None for b in bounds) else sum(bounds)  # type: ignore[arg-type]


def _bound(t: mi.Type) -> int | None:
    """The largest encoding of a value of type `t` in bytes, or None if it has no bound."""
    if isinstance(t, mi.Metadata):
        return _bound(t.type)
    if isinstance(t, (mi.IntType, mi.FloatType)):
        return NUMBER
    if isinstance(t, (mi.BoolType, mi.NoneType)):
        return 1
    if isinstance(t, mi.StrType):
        return _str_bound(t.max_length, t.pattern)
    if isinstance(t, (mi.BytesType, mi.ByteArrayType, mi.MemoryViewType)):
        return None if t.max_length is None else HEADER + t.max_length
    if isinstance(t, mi.LiteralType):
        return max(
            HEADER + len(v.encode()) if isinstance(v, str) else NUMBER for v in t.values
        )
    if isinstance(t, mi.UnionType):
        bounds = [_bound(u) for u in t.types]
        return None if any(b is None for b in bounds) else max(bounds)  # type: ignore[type-var]
    if isinstance(t, mi.TupleType):
        items = _sum([_bound(i) for i in t.item_types])
        return None if items is None else HEADER + items
    if isinstance(t, (mi.VarTupleType, mi.ListType, mi.SetType, mi.FrozenSetType)):
        item = _bound(t.item_type)
        if item is None or t.max_length is None:
            return None
        return HEADER + t.max_length * item
    if isinstance(t, mi.StructType):
        return _struct_bound(t)
    return None  # any other type (dicts, Any, dates…): not bounded here


def _key(name: str) -> int:
    return HEADER + len(name.encode())


def _struct_bound(t: mi.StructType) -> int | None:
    fields = [_bound(f.type) for f in t.fields]
    keys = 0 if t.array_like else sum(_key(f.encode_name) for f in t.fields)
    tag = 0
    if t.tag_field is not None:
        value = HEADER + len(t.tag.encode()) if isinstance(t.tag, str) else NUMBER
        tag = value + (0 if t.array_like else _key(t.tag_field))
    total = _sum(fields)
    return None if total is None else HEADER + keys + tag + total


@cache
def max_payload_bytes(cls: type[m.Message]) -> int:
    """The largest payload a valid `cls` can have: its schema's bound, at most `cls.MAX_BYTES`."""
    bound = _bound(mi.type_info(cls))
    return cls.MAX_BYTES if bound is None else min(bound, cls.MAX_BYTES)


def topic_limits() -> dict[str, int]:
    """Every topic of the contract with its payload size limit in bytes."""
    return {name: max_payload_bytes(t.message) for name, t in TOPICS.items()}


def low_pass_filters() -> list[dict[str, object]]:
    """The `low_pass_filter` rules of zenoh: each contract key on any rig, then the rest of nod/.

    zenoh applies the smallest limit of the rules whose key expression includes a message's key,
    so the catch-all must allow the largest message of the contract.
    """
    limits = topic_limits()
    rules: list[dict[str, object]] = [
        {"messages": _MESSAGES, "key_exprs": [f"nod/*/{topic}" for topic in names],
         "size_limit": size}
        for size, names in _by_size(limits).items()
    ]
    rules.append({"messages": _MESSAGES, "key_exprs": ["nod/**"],
                  "size_limit": max(limits.values())})
    return rules


def _by_size(limits: dict[str, int]) -> dict[int, list[str]]:
    """Topics grouped by limit (one rule each), smallest first."""
    out: dict[int, list[str]] = {}
    for name, size in sorted(limits.items(), key=lambda kv: (kv[1], kv[0])):
        out.setdefault(size, []).append(name)
    return out
