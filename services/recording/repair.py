"""`nod record repair FILE.mcap [--out FIXED.mcap]`: make a cut recording whole again.

A recorder killed with SIGKILL (or a host that lost power) leaves a file without its summary
and footer: the `mcap` library's standard (seeking) reader refuses it, though everything up to
the last complete record is there (`McapIn` reads it sequentially). Repair copies every
complete message, channel, schema and metadata record, in order and byte for byte, into a new
file with a proper summary and footer, and says what was lost at the cut. The original is
never changed; by default the repaired copy is FILE.repaired.mcap beside it.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from services.core.cli import Parser, fail, one_line
from services.recording.mcap_io import END_METADATA, McapIn, McapOut

PROG = "nod record repair"


@dataclass(frozen=True, slots=True)
class Repaired:
    """What a repair kept and why the source ended early (None: it was whole)."""

    messages: int
    metadata: int
    truncated: str | None


def repair(src_path: Path, out_path: Path) -> Repaired:
    """Copy the readable part of `src_path` into a complete MCAP file at `out_path`."""
    src = McapIn(src_path)
    out = McapOut(out_path)
    kept_meta = 0
    try:
        for e in src:
            out.write(out.copy_channel(e.channel, e.schema), e.message.log_time,
                      e.message.publish_time, e.message.data, e.message.sequence)
        for name, data in src.metadata:
            if name != END_METADATA:  # the source had no clean end: say what this one is
                out.metadata(name, dict(data))
                kept_meta += 1
        out.metadata(END_METADATA, {
            "messages": str(out.messages), "repaired_from": str(src_path),
            "source_truncated": src.truncated or "",
        })
    finally:
        out.finish()
    return Repaired(out.messages, kept_meta, src.truncated)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod record repair`."""
    p = Parser(prog=PROG, description=__doc__.splitlines()[0])
    p.add_argument("file", type=Path, help="the cut recording (read only)")
    p.add_argument("--out", type=Path, default=None,
                   help="where to write the repaired copy (default FILE.repaired.mcap)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Repair one file; 0 when the copy is written, 2 when the source cannot be read at all."""
    args = build_parser().parse_args(argv)
    out = args.out or args.file.with_suffix(".repaired.mcap")
    if out.resolve() == args.file.resolve():
        return fail(PROG, "--out must not be the file being repaired (it is never changed)")
    try:
        res = repair(args.file, out)
    except (OSError, ValueError) as exc:
        return fail(PROG, one_line(str(exc)))
    state = f"it was cut: {res.truncated}" if res.truncated else "it was whole"
    print(f"{PROG}: wrote {out}: {res.messages} messages, {res.metadata} metadata records "
          f"({args.file}: {state})")
    return 0
