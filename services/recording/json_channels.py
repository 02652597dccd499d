"""The channels a standard reader decodes: JSON messages, each with the JSON Schema of its type.

Since schema 3 a recording keeps every valid message as a JSON object (MCAP message encoding
`json`) on a channel whose schema (encoding `jsonschema`) is msgspec's JSON Schema of the
message class, made self-contained: the class's definition is the schema's root (no `$ref`,
no `$defs`), with `$schema` naming the draft (2020-12: tuples are `prefixItems`). Foxglove, the
`mcap` CLI and any JSON Schema validator read it without code of ours. A `bytes` field (the
JPEG of `vision/frame`) is a base64 string, the schema says so (`contentEncoding: base64`).

Readers of ours still take msgpack payloads (what the wire carries): `to_wire` turns a
recorded JSON message back into one, checked against the contract on the way
(`messages.decode_json`), so a replay of a JSON recording sends what the rig sent.
"""

from __future__ import annotations

import json
from typing import Any

import msgspec

from services.core import messages as m

JSON_ENCODING = "json"  # the message encoding of today's recordings
SCHEMA_ENCODING = "jsonschema"
DRAFT = "https://json-schema.org/draft/2020-12/schema"


def _inline(node: Any, defs: dict[str, Any]) -> Any:
    """`node` with every `{"$ref": "#/$defs/X"}` replaced by X's definition (recursively)."""
    if isinstance(node, dict):
        ref = node.get("$ref")
        if isinstance(ref, str) and ref.startswith("#/$defs/"):
            return _inline(defs[ref.removeprefix("#/$defs/")], defs)
        return {k: _inline(v, defs) for k, v in node.items()}
    if isinstance(node, list):
        return [_inline(v, defs) for v in node]
    return node


def schema(cls: type[m.Message]) -> dict[str, Any]:
    """The self-contained JSON Schema of a message class (its definition at the root)."""
    raw = msgspec.json.schema(cls)
    root = _inline({k: v for k, v in raw.items() if k != "$defs"}, raw.get("$defs", {}))
    return {"$schema": DRAFT, **root}


def schema_data(cls: type[m.Message]) -> bytes:
    """The schema record's data: `schema(cls)` as JSON, keys sorted (one record per class)."""
    return json.dumps(schema(cls), sort_keys=True).encode()


def to_wire(cls: type[m.Message], data: bytes) -> bytes:
    """A recorded JSON message as the msgpack payload it travelled as (MessageError if invalid)."""
    return m.encode(m.decode_json(cls, data))
