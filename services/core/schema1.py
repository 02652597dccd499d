"""The reader of schema 1: payloads of the paper's keys from before one schema for any N.

Until schema 3 the paper's keys carried scalars and colours (schema 1): the table as a `red` and
a `blue` box, ẑ_h, z_r and b_r as one signed number `value`, a press by its `colour`, the
protocol's events and results with O a colour and no option set. Recordings made then (the
golden's among them) still replay, convert and re-run through the decision model: every
recorded payload passes through `upgrade` before it is decoded, which rewrites a schema-1
payload as the schema-3 message that says the same thing (the two options red and blue, the
signed z as the vector (z, -z): `messages.Opinions`) and returns any other payload unchanged.

The rewrite works on the raw map, not on old message classes: the schema-3 decoder still checks
every field of the result, so a schema-1 payload that was garbage is refused as garbage.
Schema 2 (the retired `options/*` keys of three or more boxes) has no reader: those keys are no
longer in the contract, and their recordings replay with the code that made them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import msgspec

from services.core.messages import SCHEMA_VERSION
from services.model.geometry import COLOURS

OLD_VERSION = 1
_PAPER = list(COLOURS)


def _layout(old: dict[str, Any]) -> dict[str, Any]:
    new = {k: v for k, v in old.items() if k not in ("red", "blue")}
    new["options"] = _PAPER
    new["boxes"] = [old.get("red"), old.get("blue")]
    return new


def _opinion(old: dict[str, Any]) -> dict[str, Any]:
    new = {k: v for k, v in old.items() if k != "value"}
    new["options"] = _PAPER
    value = old.get("value", 0.0)
    # A number becomes the paper's vector (z, -z); anything else is left for the decoder to
    # refuse (negating it here would raise before the one-line error could be written).
    new["values"] = [value, -value] if isinstance(value, (int, float)) and not isinstance(
        value, bool) else [value, value]
    return new


def _press(old: dict[str, Any]) -> dict[str, Any]:
    new = {k: v for k, v in old.items() if k != "colour"}
    new["option"] = old.get("colour", "red")
    return new


def _with_options(old: dict[str, Any]) -> dict[str, Any]:
    return {**old, "options": _PAPER}


# The topics whose messages changed shape, and how; every other topic's payload keeps its fields.
_REWRITE: dict[str, Callable[[dict[str, Any]], dict[str, Any]]] = {
    "vision/layout": _layout,
    "decision/z_h": _opinion,
    "decision/z_r": _opinion,
    "decision/b_r": _opinion,
    "actuation/press": _press,
    "experiment/trial": _with_options,
    "experiment/result": _with_options,
}


def version_of(payload: bytes) -> int | None:
    """The schema version `v` of a payload (None: not a msgpack map with an integer `v`)."""
    try:
        raw = msgspec.msgpack.decode(payload)
    except msgspec.DecodeError:
        return None
    v = raw.get("v") if isinstance(raw, dict) else None
    return v if isinstance(v, int) and not isinstance(v, bool) else None


def upgrade(topic: str, payload: bytes) -> bytes:
    """A payload of `topic` in today's schema: a schema-1 one rewritten, any other unchanged."""
    try:
        raw = msgspec.msgpack.decode(payload)
    except msgspec.DecodeError:
        return payload
    if not isinstance(raw, dict) or raw.get("v") != OLD_VERSION:
        return payload
    rewrite = _REWRITE.get(topic)
    new = rewrite(raw) if rewrite is not None else dict(raw)
    new["v"] = SCHEMA_VERSION
    return msgspec.msgpack.encode(new)
