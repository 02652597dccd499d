"""`nod monitor`: every key of a rig, live in Rerun (native viewer, web viewer or `.rrd` file).

One Zenoh subscriber on `nod/<rig>/**` copies each sample's bytes into a bounded `Inbox` (never
blocking Zenoh's delivery thread; the keys in `bridge.NOT_SHOWN`, the simulated camera, are
skipped there without a copy); one logger thread decodes them with the contract and hands
them to the `RerunBridge`. Hand poses and camera frames are dropped (oldest first) when the
viewer falls behind; opinions and events have a large queue and are counted if they ever drop. The
monitor is its own process and only subscribes, so it cannot slow the control loop.

Sinks (any combination): `--spawn` starts the native viewer (the default when no sink is given),
`--serve-web` hosts a gRPC server plus the web viewer for a lab screen, `--save FILE.rrd` writes a
recording that `rerun FILE.rrd` opens, `--viewer-url` streams to a viewer already running.
SIGINT/SIGTERM drain the queue, flush and close the recording cleanly.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
import uuid
from collections import Counter
from pathlib import Path
from typing import Any

import rerun as rr
import zenoh

from services.core import messages as m
from services.core.cli import PORT, fabric_parser, fail, int_in, one_line
from services.core.contract import TOPICS
from services.core.keys import Keys
from services.core.node import install_signal_handlers, setup_logging
from services.core.session import Fabric, open_session
from services.monitor.bridge import NOT_SHOWN, RerunBridge
from services.monitor.inbox import Inbox, Item, lane_of
from services.monitor.offline import log_recording
from services.monitor.sinks import ViewerWatch, open_sinks
from services.views.entities import APPLICATION_ID

log = logging.getLogger("nod.monitor")
STATUS_PERIOD_S = 10.0
ALIVE_PREFIX = "@alive/"  # inbox topic of a liveliness change (not a key of the contract)


class Monitor:
    """Zenoh subscription → bounded inbox → one logger thread → Rerun."""

    def __init__(
        self, session: zenoh.Session, keys: Keys, bridge: RerunBridge, inbox: Inbox
    ) -> None:
        self.session = session
        self.keys = keys
        self.bridge = bridge
        self.inbox = inbox
        self.types: dict[str, type[m.Message]] = {name: t.message for name, t in TOPICS.items()}
        self.bad: Counter[str] = Counter()
        self.unknown: Counter[str] = Counter()
        self.skipped: Counter[str] = Counter()  # samples of keys not shown (NOT_SHOWN)
        self.errors = 0
        self._prefix = f"nod/{keys.rig}/"
        self._alive_prefix = f"nod/{keys.rig}/alive/"
        self._handles: list[Any] = []
        self._token: Any = None
        self._thread = threading.Thread(target=self._drain, name="monitor-logger", daemon=True)
        self._last_status = time.monotonic()
        self._reported: Counter[str] = Counter()

    def start(self) -> None:
        """Start the logger thread, then subscribe to every key and to service liveliness."""
        self.bridge.log_styles()
        self._thread.start()
        self._handles.append(self.session.declare_subscriber(self.keys.all, self._on_sample))
        self._handles.append(
            self.session.liveliness().declare_subscriber(
                f"{self._alive_prefix}*", self._on_alive, history=True
            )
        )
        # Last: once others see the token, the subscription is already declared.
        self._token = self.session.liveliness().declare_token(self.keys.alive("monitor"))

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh thread: copy the payload into the inbox and return at once."""
        key = str(sample.key_expr)
        topic = key[len(self._prefix) :]
        if topic in NOT_SHOWN:  # e.g. sim/camera: 30 Hz full-size JPEGs, vision's input only
            self.skipped[topic] += 1
            return
        self.inbox.put(lane_of(topic), Item(topic, sample.payload.to_bytes()))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        service = str(sample.key_expr)[len(self._alive_prefix) :]
        if service != "monitor":
            alive = b"1" if sample.kind == zenoh.SampleKind.PUT else b"0"
            self.inbox.put("events", Item(ALIVE_PREFIX + service, alive))

    # -- logger thread -------------------------------------------------------------------------

    def _drain(self) -> None:
        while True:
            batch = self.inbox.get_batch(timeout=0.2)
            if not batch and self.inbox.closed:
                return
            for item in batch:
                self._log_one(item)
            if time.monotonic() - self._last_status >= STATUS_PERIOD_S:
                self._status()

    def _log_one(self, item: Item) -> None:
        if item.topic.startswith(ALIVE_PREFIX):
            service, up = item.topic[len(ALIVE_PREFIX) :], item.payload == b"1"
            self.bridge.note(
                f"service {service} {'up' if up else 'DOWN (liveliness lost)'}",
                level="INFO" if up else "WARN",
                t_ns=self.bridge.last_t_ns or time.time_ns(),
            )
            return
        cls = self.types.get(item.topic)
        if cls is None:
            self.unknown[item.topic] += 1  # e.g. a key of a newer contract: ignored, counted
            return
        try:
            msg = m.decode(cls, item.payload)
        except m.MessageError as exc:
            self.bad[item.topic] += 1
            if self.bad[item.topic] <= 5:
                log.warning("bad message on %s: %s", item.topic, exc)
            return
        try:
            self.bridge.log(item.topic, msg)
        except Exception:  # a bridge bug on one message must not stop the monitor
            self.errors += 1
            if self.errors <= 5:
                log.exception("logging %s to Rerun failed", item.topic)

    def _status(self) -> None:
        self._last_status = time.monotonic()
        ib = self.inbox
        log.info(
            "monitor: %d logged; queue %d (high water %s); dropped %s; bad %s%s",
            self.bridge.logged,
            ib.depth(),
            dict(ib.high_water),
            dict(ib.dropped) or "none",
            dict(self.bad) or "none",
            f"; unknown keys {dict(self.unknown)}" if self.unknown else "",
        )
        lost = ib.dropped["events"] - self._reported["events"]
        if lost > 0:
            self._reported["events"] = ib.dropped["events"]
            self.bridge.note(f"monitor fell behind: {lost} opinion/event samples dropped", "WARN")

    # -- shutdown ------------------------------------------------------------------------------

    def close(self, timeout: float = 10.0) -> None:
        """Stop subscribing, let the logger drain what is queued, and wait for it."""
        for h in self._handles:
            h.undeclare()
        self._handles.clear()
        if self._token is not None:
            self._token.undeclare()
            self._token = None
        self.inbox.close()
        self._thread.join(timeout)
        if self._thread.is_alive():
            log.warning("logger still busy after %.0f s; %d left", timeout, self.inbox.depth())
        self._status()


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod monitor`."""
    p = fabric_parser(
        "nod monitor",
        "Watch every key of a rig in Rerun: opinions, table, arm, eyes, trial "
        "events and safety, stamped with each message's own time. With no sink flag the "
        "native viewer is spawned.",
    )
    g = p.add_argument_group("rerun sinks (combine freely)")
    g.add_argument("--spawn", action="store_true", help="start the native Rerun viewer")
    g.add_argument(
        "--serve-web", action="store_true", help="host the web viewer (for a lab screen)"
    )
    g.add_argument("--web-port", type=PORT, default=9090, help="web viewer port (9090)")
    g.add_argument("--grpc-port", type=PORT, default=9876, help="gRPC port of --serve-web (9876)")
    g.add_argument("--save", type=Path, default=None, metavar="FILE.rrd", help="write a recording")
    g.add_argument(
        "--no-footer",
        action="store_true",
        help="no chunk index at the end of --save (flat memory for recordings of hours; "
        "`rerun rrd optimize` adds one later)",
    )
    g.add_argument(
        "--viewer-url",
        default=None,
        metavar="URL",
        help="stream to a running viewer, e.g. rerun+http://host:9876/proxy",
    )
    g.add_argument(
        "--memory-limit",
        default="1GiB",
        help="memory the served/spawned viewer keeps before dropping the oldest data (1GiB)",
    )
    q = p.add_argument_group("queues")
    q.add_argument("--hand-queue", type=int_in(1, 10**6), default=240,
                   help="hand poses held (lossy; 240)")
    q.add_argument("--event-queue", type=int_in(1, 10**7), default=200_000,
                   help="opinions/events held (200000)")
    g.add_argument(
        "--viewer-grace",
        type=float,
        default=30.0,
        help="seconds a closed viewer is waited for before stopping or warning (30)",
    )
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument(
        "--from", dest="recording", type=Path, default=None, metavar="FILE.mcap",
        help="show a recording (nod record's) instead of a rig: every message through the same "
        "views, then exit (with --save: an .rrd the recording's rerun-blueprint.rbl lays out)",
    )
    p.add_argument("-v", "--verbose", action="store_true")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the monitor until SIGINT/SIGTERM (or --duration); exit 0 after a clean flush."""
    args = build_parser().parse_args(argv)
    setup_logging(args.verbose)
    if args.recording is not None:
        return _show_recording(args)
    try:
        keys = Keys(args.rig)
        inbox = Inbox(events=args.event_queue, hand=args.hand_queue)
        session = open_session(Fabric.from_args(args).zenoh_config())
    except (ValueError, OSError, ConnectionError) as exc:
        return fail("nod monitor", exc)
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    try:
        sinks = open_sinks(rec, args)
    except (RuntimeError, OSError, ValueError) as exc:  # no viewer binary, port taken, bad path
        session.close()
        return fail("nod monitor", f"cannot open the Rerun sink: {exc}")
    for line in sinks.lines:
        print(f"nod monitor: {line}", flush=True)
    rec.send_recording_name(f"nod {keys.rig}")
    monitor = Monitor(session, keys, RerunBridge(rec), inbox)
    stop = threading.Event()
    install_signal_handlers(stop, grace_s=30.0)  # time to write an .rrd footer
    monitor.start()
    log.info("monitor up: logging %s to Rerun", keys.all)
    deadline = None if args.duration is None else time.monotonic() + args.duration
    watch = ViewerWatch(sinks.viewer_urls)
    warned = 0.0
    try:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            stop.wait(0.2)  # short waits: signal handlers run between them
            gone = watch.gone_for()
            if gone < args.viewer_grace:
                continue
            if not sinks.keeps_data:
                log.warning("the viewer is gone (%.0f s): stopping, nothing else records", gone)
                break
            if time.monotonic() - warned > 60:
                warned = time.monotonic()
                log.warning(
                    "a viewer is unreachable for %.0f s (the recording goes on; Rerun does not "
                    "reconnect, and buffers without bound for a viewer that never connected, "
                    "rerun#11519): restart the monitor to watch live again",
                    gone,
                )
    finally:
        monitor.close()
        session.close()
        try:
            rec.flush(timeout_sec=10.0)
        except RuntimeError as exc:  # e.g. the viewer was closed: the .rrd sink still flushes
            log.warning("flushing to Rerun: %s", exc)
        rec.disconnect()  # closes the .rrd (with its footer) and the viewer connections
    log.info(
        "monitor stopped: %d messages logged, dropped %s",
        monitor.bridge.logged,
        dict(inbox.dropped) or "none",
    )
    return 0



def _show_recording(args: argparse.Namespace) -> int:
    """`--from FILE.mcap`: the recording through the bridge into the sinks; 2 if unreadable."""
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    try:
        sinks = open_sinks(rec, args)
    except (RuntimeError, OSError, ValueError) as exc:
        return fail("nod monitor", f"cannot open the Rerun sink: {exc}")
    for line in sinks.lines:
        print(f"nod monitor: {line}", flush=True)
    rec.send_recording_name(f"nod {args.recording.name}")
    try:
        shown = log_recording(RerunBridge(rec), args.recording)
    except (OSError, ValueError) as exc:
        return fail("nod monitor", one_line(str(exc)))
    finally:
        rec.flush(timeout_sec=10.0)
        rec.disconnect()
    cut = f"; the file was cut: {shown.truncated}" if shown.truncated else ""
    print(f"nod monitor: {args.recording}: {shown.logged} messages shown, {shown.undecodable} "
          f"undecodable{cut}", flush=True)
    return 0

if __name__ == "__main__":
    raise SystemExit(main())
