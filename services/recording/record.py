"""`nod record --out FILE.mcap`: every message of a rig into one MCAP file any viewer opens.

It subscribes to `nod/<rig>/**` (or the `--only` keys) and writes each validated message as JSON
on its key's channel, with its JSON Schema (see `services.recording.mcap_io` for the layout),
plus a Foxglove layout and a Rerun blueprint as attachments (`services.recording.attachments`).
It only listens: no liveliness token, nothing published. `nod record convert OLD NEW` rewrites
an older recording (msgpack) as today's (`services.recording.convert`).

- Bounded memory: zenoh's thread stamps and queues each sample (`services.core.tap.Tap`, at most
  10 000 samples and `--queue-mb` of payloads); what overflows is dropped and counted, never
  blocking the network. The main thread validates and writes.
- Crash-safe: the chunk in progress is closed and handed to the OS every `--flush-s` (1 s), so a
  recorder killed with SIGKILL leaves a file readable up to its last complete chunk (read it with
  `McapIn`, or the mcap library's stream reader). SIGTERM and Ctrl-C finish the file properly
  (summary and indexes), as does `--duration`.
- A payload that fails validation is kept on an `invalid` channel of its key (publish_time =
  log_time, the first error in the channel metadata) rather than dropped: a forged or broken
  message is evidence of what happened on the rig, and keeping it apart means no reader or
  player mistakes it for a message of the contract.
- At exit one line: messages, channels, bytes, invalid, drops.
"""

from __future__ import annotations

import argparse
import logging
import os
import socket
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import zenoh

from services.core import messages as m
from services.core.cli import add_params_arg, fabric_parser, fail, one_line, positive_float
from services.core.config import load_params
from services.core.contract import TOPICS
from services.core.keys import Keys, topic_of
from services.core.node import install_signal_handlers, package_version, setup_logging
from services.core.provenance import PROVENANCE_METADATA, metadata_arg
from services.core.session import Fabric, open_session
from services.core.tap import QUEUE_MAX, Tap
from services.recording.attachments import attach_views
from services.recording.mcap_io import (
    END_METADATA,
    FILE_METADATA,
    SESSION_METADATA,
    McapOut,
)

PROG = "nod record"
log = logging.getLogger("nod.record")
MAX_INVALID_CHANNELS = 64  # keys with invalid payloads that get a channel; more are counted only
READY = "nod record: recording"  # the first line on stdout once subscribed (launchers wait on it)


class Recorder:
    """Validates arrivals and writes them to an `McapOut` (no zenoh here: testable alone)."""

    def __init__(self, out: McapOut, *, images: bool = False) -> None:
        self.out = out
        self.images = images
        self.sessions: list[str] = []
        self.counts: Counter[str] = Counter()
        self.invalid: Counter[str] = Counter()
        self.invalid_skipped = 0
        self.first_error: dict[str, str] = {}

    def add(self, key: str, payload: bytes, log_time_ns: int) -> None:
        """Record one payload that arrived on `key` at `log_time_ns` (wall clock)."""
        topic = topic_of(key)
        if topic is None:
            self._invalid(key, payload, log_time_ns, "not a key of the contract")
            return
        try:
            msg = m.decode(TOPICS[topic].message, payload)
        except m.MessageError as exc:
            self._invalid(key, payload, log_time_ns, str(exc))
            return
        self.out.write_message(key, msg, log_time_ns)
        self.counts[key] += 1
        session = msg.session if isinstance(msg, m.TrialEvent) else ""
        if session and session not in self.sessions:
            self.sessions.append(session)
            self.out.metadata(
                SESSION_METADATA, {"session": session, "key": key, "seen_ns": log_time_ns}
            )
        if self.images and isinstance(msg, m.VisionFrame):
            self.out.write_image(key, msg, log_time_ns)

    def _invalid(self, key: str, payload: bytes, log_time_ns: int, why: str) -> None:
        self.invalid[key] += 1
        if key not in self.first_error:
            if len(self.first_error) >= MAX_INVALID_CHANNELS:
                self.invalid_skipped += 1
                return
            self.first_error[key] = why
            log.warning("invalid payload on %s kept apart: %s", key, why[:200])
        self.out.write(self.out.raw_channel(key, self.first_error[key]), log_time_ns,
                       log_time_ns, payload)


class Excluder:
    """The `--exclude` filter: keys matching one of its expressions are not recorded."""

    def __init__(self, exprs: list[str]) -> None:
        self.exprs = [zenoh.KeyExpr(e) for e in exprs]
        self.count = 0
        self._known: dict[str, bool] = {}

    def __call__(self, key: str) -> bool:
        """True if `key` is excluded (answers are cached per key; excluded ones counted)."""
        hit = self._known.get(key)
        if hit is None:
            try:
                k = zenoh.KeyExpr(key)
                hit = any(e.intersects(k) for e in self.exprs)
            except zenoh.ZError:
                hit = False
            if len(self._known) < 10_000:
                self._known[key] = hit
        self.count += hit
        return hit


def start_metadata(args: argparse.Namespace, exprs: list[str]) -> dict[str, object]:
    """The `nod` metadata record: who recorded what, where, when, with which parameters."""
    now = time.time_ns()
    meta: dict[str, object] = {
        "rig": args.rig,
        "host": socket.gethostname(),
        "nod_hri_version": package_version(),
        "schema_version": str(m.SCHEMA_VERSION),
        "started_ns": str(now),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z", time.localtime(now / 1e9)),
        "keys": ",".join(exprs),
        "excluded": ",".join(key_exprs(args.exclude, args.rig)) if args.exclude else "",
        "pid": str(os.getpid()),
    }
    if args.params is not None:
        meta["params_file"] = str(args.params)
        meta["params_toml"] = Path(args.params).read_text(encoding="utf-8")
        meta["params"] = load_params(args.params).summary()
    for item in args.meta or ():
        name, _, value = item.partition("=")
        meta[name] = value
    return meta


def key_exprs(only: list[str] | None, rig: str) -> list[str]:
    """The key expressions to subscribe to: `nod/<rig>/**`, or each `--only` key."""
    if not only:
        return [Keys(rig).all]
    exprs = []
    for key in only:
        text = key.strip().strip("/")
        expr = text if text == "nod" or text.startswith("nod/") else f"nod/{rig}/{text}"
        try:
            zenoh.KeyExpr(expr)
        except zenoh.ZError:
            raise ValueError(f"--only {key!r} is not a key expression") from None
        exprs.append(expr)
    return exprs


def _meta_item(text: str) -> str:
    if "=" not in text or not text.partition("=")[0]:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    return text


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod record`."""
    p = fabric_parser(
        PROG,
        "Record every key of a rig (or the --only keys) into an MCAP file: the "
        "original payloads, one channel per key. Ctrl-C or SIGTERM finish the file; a killed "
        "recorder leaves it readable up to its last chunk (flushed every --flush-s).",
    )
    p.add_argument("--out", type=Path, required=True, metavar="FILE.mcap", help="the file")
    p.add_argument(
        "--only", action="append", default=None, metavar="KEY",
        help="record only this key (relative to --rig, or full; wildcards allowed); repeatable",
    )
    p.add_argument(
        "--exclude", action="append", default=None, metavar="KEY",
        help="leave this key out (e.g. sim/camera: ~1 MB/s of rendered frames); repeatable",
    )
    p.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C/SIGTERM)")
    add_params_arg(p)
    p.add_argument(
        "--meta", action="append", default=None, metavar="KEY=VALUE", type=_meta_item,
        help="an extra entry of the file's `nod` metadata (e.g. session=...); repeatable",
    )
    p.add_argument("--provenance", type=metadata_arg, default=None, metavar="JSON",
                   help="the session's provenance (a JSON object): a `provenance` metadata record")
    p.add_argument("--flush-s", type=positive_float, default=1.0, metavar="S",
                   help="close a chunk and flush it to the OS at least this often (1 s)")
    p.add_argument("--chunk-kb", type=positive_float, default=1024, metavar="KB",
                   help="close a chunk when it holds this much (1024 kB)")
    p.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd",
                   help="chunk compression (zstd)")
    p.add_argument("--queue-mb", type=positive_float, default=64, metavar="MB",
                   help="payload bytes waiting to be written at most; more are dropped (64)")
    p.add_argument(
        "--images", action="store_true",
        help="also write vision/frame JPEGs on a Foxglove CompressedImage channel "
        "(<key>/image, JSON); the frames are always in their msgpack channel",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log at debug level")
    return p


def main(argv: list[str] | None = None) -> int:
    """Record until Ctrl-C, SIGTERM or --duration; 2 on bad flags or an unreachable router.

    `nod record repair FILE` makes a cut recording whole (`services.recording.repair`), `nod
    record convert OLD NEW` rewrites an older one in today's form (`services.recording.convert`).
    """
    if argv is None:
        argv = sys.argv[1:]
    if argv[:1] == ["repair"]:
        from services.recording.repair import main as repair

        return repair(argv[1:])
    if argv[:1] == ["convert"]:
        from services.recording.convert import main as convert

        return convert(argv[1:])
    args = build_parser().parse_args(argv)
    setup_logging(args.verbose)
    try:
        exprs = key_exprs(args.only, args.rig)
        meta = start_metadata(args, exprs)
        fabric = Fabric.from_args(args)
        session = open_session(fabric.zenoh_config())
    except (ValueError, OSError, ConnectionError, zenoh.ZError) as exc:
        return fail(PROG, one_line(str(exc)))
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        out = McapOut(args.out, chunk_bytes=int(args.chunk_kb * 1024),
                      compression=args.compression)
    except OSError as exc:
        session.close()
        return fail(PROG, f"cannot write {args.out}: {exc}")
    try:
        return _record(args, session, out, exprs, meta)
    finally:
        session.close()


def _record(args: argparse.Namespace, session: zenoh.Session, out: McapOut, exprs: list[str],
            meta: dict[str, object]) -> int:
    stop = threading.Event()
    install_signal_handlers(stop, grace_s=10.0)  # the summary of a long file takes a moment
    recorder = Recorder(out, images=args.images)
    excluded = Excluder(key_exprs(args.exclude, args.rig) if args.exclude else [])
    out.metadata(FILE_METADATA, meta)
    if args.provenance:
        out.metadata(PROVENANCE_METADATA, args.provenance)
    attach_views(out, args.rig, time.time_ns())
    out.flush()
    t0 = time.monotonic()
    deadline = None if args.duration is None else t0 + args.duration
    tap = Tap(session, exprs, maxsize=QUEUE_MAX, max_bytes=int(args.queue_mb * 1e6))
    print(f"{READY} {', '.join(exprs)} to {args.out}", flush=True)
    next_flush = t0 + args.flush_s
    try:
        while not stop.is_set():
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            if now >= next_flush:
                out.flush()
                next_flush = now + args.flush_s
            until = next_flush if deadline is None else min(next_flush, deadline)
            item = tap.next(until)
            if item is not None and not excluded(item.key):
                recorder.add(item.key, item.payload, item.wall_ns)
    finally:
        tap.close()
        while (item := tap.next(time.monotonic())) is not None:  # what arrived before close
            if not excluded(item.key):
                recorder.add(item.key, item.payload, item.wall_ns)
        elapsed = time.monotonic() - t0
        out.metadata(END_METADATA, {
            "finished_ns": str(time.time_ns()),
            "messages": str(out.messages),
            "dropped": str(tap.dropped),
            "invalid": str(sum(recorder.invalid.values())),
            "excluded": str(excluded.count),
            "sessions": ",".join(recorder.sessions),
        })
        out.finish()
    print(summary_line(args.out, recorder, out, tap.dropped, elapsed), flush=True)
    return 0


def summary_line(path: Path, recorder: Recorder, out: McapOut, dropped: int,
                 elapsed: float) -> str:
    """The one line printed at exit."""
    size = out.size() if not out.finished else path.stat().st_size
    invalid = sum(recorder.invalid.values())
    text = (
        f"{PROG}: {path}: {out.messages} messages on {out.channel_count} channels, "
        f"{size / 1e6:.2f} MB ({out.payload_bytes / 1e6:.2f} MB of payloads), "
        f"{invalid} invalid, {dropped} dropped, {elapsed:.1f} s"
    )
    if recorder.sessions:
        text += f"; session(s) {', '.join(recorder.sessions)}"
    return text


if __name__ == "__main__":
    raise SystemExit(main())
