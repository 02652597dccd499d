"""`nod record convert OLD.mcap NEW.mcap`: an older recording rewritten as today's.

Recordings made before JSON channels keep each payload as the msgpack it travelled as (schema 1
before one schema for any N, or schema 3), which Foxglove and the `mcap` tools show as opaque
bytes. Convert reads one (also one cut short) and writes every message of the contract as
today's recorder would: JSON in today's schema on its key's channel with its JSON Schema
(`McapOut.rewrite`: a schema-1 payload upgraded by `services.core.schema1`), at its original
log and publish times. Invalid payloads and derived images are copied as they were; a payload of
a valid channel that no longer passes the contract moves to its key's invalid channel.

Every metadata record is kept, in order; a `nod.converted` record says what it was converted
from (the file, its SHA-256, its message encodings and schema versions, whether it was cut) and
by which nod-hri. The viewers' layouts are attached for the recording's rig; attachments of
the source that are not ours are kept. The source is never changed.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

from services.core import messages as m
from services.core.cli import Parser, fail, one_line
from services.core.node import package_version
from services.core.provenance import file_sha256
from services.core.schema1 import version_of
from services.recording.attachments import NAMES, attach_views
from services.recording.mcap_io import MSGPACK_ENCODING, McapIn, McapOut, rig_of

PROG = "nod record convert"
CONVERTED_METADATA = "nod.converted"


@dataclass(frozen=True, slots=True)
class Converted:
    """What a conversion wrote and what it read."""

    messages: int
    encodings: tuple[str, ...]  # the source's message encodings
    versions: tuple[int, ...]  # the schema versions of the source's valid messages
    truncated: str | None


def _rig(src: McapIn) -> str:
    """The recording's rig: its `nod` metadata's, else its first key's, else rig1."""
    rig = src.file_metadata().get("rig")
    if rig:
        return rig
    for e in src:
        return rig_of(e.key) or "rig1"
    return "rig1"


def convert(src_path: Path, out_path: Path) -> Converted:
    """Rewrite the recording at `src_path` as today's at `out_path`."""
    src = McapIn(src_path)
    rig = _rig(src)
    digest = file_sha256(src_path)
    out = McapOut(out_path)
    encodings: set[str] = set()
    versions: set[int] = set()
    failed = True
    try:
        attach_views(out, rig, time.time_ns())
        for e in src:
            encodings.add(e.channel.message_encoding)
            if e.valid:
                version = (version_of(e.message.data)
                           if e.channel.message_encoding == MSGPACK_ENCODING else m.SCHEMA_VERSION)
                if version is not None:
                    versions.add(version)
            out.rewrite(e)
        for name, data in src.metadata:
            out.metadata(name, dict(data))
        for att in src.attachments:
            if att.name not in NAMES:
                out.attach(att.name, att.media_type, att.data, att.log_time)
        out.metadata(CONVERTED_METADATA, {
            "from_file": str(src_path),
            "from_sha256": digest,
            "from_message_encodings": ",".join(sorted(encodings)),
            "from_schema_versions": ",".join(map(str, sorted(versions))),
            "from_truncated": src.truncated or "",
            "converted_ns": str(time.time_ns()),
            "nod_hri_version": package_version(),
            "schema_version": str(m.SCHEMA_VERSION),
            "messages": str(out.messages),
        })
        failed = False
    finally:
        out.finish()
        if failed:  # no half-converted file left behind
            Path(out_path).unlink(missing_ok=True)
    return Converted(out.messages, tuple(sorted(encodings)), tuple(sorted(versions)),
                     src.truncated)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod record convert`."""
    p = Parser(prog=PROG, description=__doc__.splitlines()[0])
    p.add_argument("old", type=Path, help="the older recording (read only)")
    p.add_argument("new", type=Path, help="the converted recording to write")
    return p


def main(argv: list[str] | None = None) -> int:
    """Convert one file; 0 when written, 2 when the source cannot be read or NEW is OLD."""
    args = build_parser().parse_args(argv)
    if args.new.resolve() == args.old.resolve():
        return fail(PROG, "NEW must not be OLD (the source is never changed)")
    try:
        res = convert(args.old, args.new)
    except (OSError, ValueError) as exc:
        return fail(PROG, one_line(str(exc)))
    cut = f"; {args.old} was cut: {res.truncated}" if res.truncated else ""
    print(f"{PROG}: wrote {args.new}: {res.messages} messages as JSON in schema "
          f"{m.SCHEMA_VERSION} (from {', '.join(res.encodings) or 'nothing'}, schema "
          f"{', '.join(map(str, res.versions)) or '-'}){cut}")
    return 0
