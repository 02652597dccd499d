"""`nod vision`: camera capture and hand tracking, publishing what the sim publishes.

Keys (see docs/vision.md):
- `vision/hand` (HandPose) for every frame captured, at camera rate: `seq` = the frame's number
  (gaps = frames dropped), `t_ns` = its capture time, `detected`, the landmarks and their mean
  `center` in normalised image coordinates, `source` = the tracker's name. No hand → detected
  false and nothing else; no frame (a lost camera) → nothing at all, so the key goes stale.
- the table, once at start (or once found) and then at 1 Hz, and answered to a zenoh `get` on
  the same key for late joiners, on `vision/layout` (Layout: the option set, a box per option,
  the commit line): the paper's two options, the buzzer boxes and the commit line from
  `--calibration` (else the params file's `[layout]`, else SPEC's defaults); three or more, the
  boxes from a `--calibration` file with a box per option, else found by their colours in the
  camera's frames (`calibration.find_option_boxes`; nothing is published until every box is
  found, each tracked frame tries again, with a warning every 100 frames).
- `vision/frame` (VisionFrame): a small JPEG with the boxes and the hand drawn, at
  `--frames-key-hz` (default 2, 0 = off), encoded on the node's tick thread, never on the
  tracking thread that publishes hand poses.

One service for any number of options on one key space: what differs with N is where the table's
boxes come from (`PaperTable`, `OptionsTable`), picked by `vision_table`.

The tracking thread takes the newest captured frame, tracks it and publishes the pose; the node's
main thread runs the low-rate ticks (layout, monitor frame, a 10 s status line). On the way out
every thread of ours is stopped and joined before `main` returns (`stop_threads`), and if one
cannot be, the process exits without the interpreter's finalization (`exit_now`).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any, NoReturn

import cv2
import zenoh

from services.core import messages as m
from services.core.cli import add_options_arg, add_params_arg, fabric_parser, fail, int_in
from services.core.clock import add_clock_args
from services.core.config import ConfigError, load_with_options
from services.core.contract import check_publisher
from services.core.node import Node, declare_publisher, setup_logging
from services.core.session import Fabric
from services.model.geometry import COLOURS, CommitLine, OptionsLayout, TableLayout
from services.model.schedule import OptionsSchedule
from services.vision.calibration import (
    CalibrationError,
    MissingBoxError,
    find_option_boxes,
    load_boxes,
    load_calibration,
    load_commit,
)
from services.vision.capture import (
    Capture,
    CaptureError,
    CaptureParams,
    Frame,
    open_video,
    parse_source,
)
from services.vision.overlay import monitor_jpeg
from services.vision.trackers import (
    TRACKERS,
    HandTracker,
    TrackerOptions,
    TrackerUnavailableError,
    TrackResult,
    make_tracker,
)
from services.vision.zenoh_camera import ZenohCamera

log = logging.getLogger("nod.vision")


class HandPublisher:
    """`vision/hand`: one HandPose per frame, carrying the frame's own `seq` and `t_ns`.

    A live camera publishes express with congestion control DROP (the newest pose matters and
    the capture must never block); a recording replayed as fast as possible publishes with BLOCK,
    so a slow subscriber slows the replay down instead of losing poses.
    """

    def __init__(self, node: Node, *, lossless: bool) -> None:
        self.key = node.keys.topic("vision/hand")
        qos = check_publisher("vision/hand", node.service).qos
        if lossless:  # a file replayed as fast as possible: never drop, batch freely
            qos = dataclasses.replace(qos, congestion="block", express=False)
        self._pub = declare_publisher(node.session, self.key, qos)

    def put(self, frame: Frame, result: TrackResult, source: str) -> m.HandPose:
        """Build, validate, encode and publish the pose of one frame."""
        if result.detected:
            msg = m.HandPose(
                seq=frame.seq,
                t_ns=frame.t_ns,
                detected=True,
                center=result.center,
                landmarks=result.landmarks,
                source=source,
            )
        else:
            msg = m.HandPose(seq=frame.seq, t_ns=frame.t_ns, detected=False, source=source)
        self._pub.put(m.encode(msg))
        return msg


class PaperTable:
    """The paper's two options: red and blue, known at start."""

    names: tuple[str, ...] = COLOURS

    def __init__(self, layout: TableLayout) -> None:
        self.layout: TableLayout | OptionsLayout | None = layout
        self.fields: dict[str, Any] | None = m.layout_fields(self.names, layout)

    def look(self, image: Any) -> None:
        """Nothing to find: the boxes came from the calibration, the params or SPEC."""


class OptionsTable:
    """Three or more options: their boxes given or found.

    The boxes are given (a calibration file with one per option) or found by their colours in
    the camera's frames, tried on every tracked frame until all are found.
    """

    def __init__(
        self, names: tuple[str, ...], commit: CommitLine, boxes: OptionsLayout | None = None
    ) -> None:
        self.names = names
        self.commit = commit
        self.layout: TableLayout | OptionsLayout | None = None
        self.fields: dict[str, Any] | None = None
        self._tries = 0
        if boxes is not None:
            self._found(boxes)

    def _found(self, boxes: OptionsLayout) -> None:
        self.fields = m.layout_fields(self.names, boxes)
        self.layout = boxes  # after the fields: whoever sees the layout can publish them

    def look(self, image: Any) -> None:
        """Until found: find every option's box by its colour in this frame."""
        if self.fields is not None:
            return
        try:
            boxes = find_option_boxes(image, self.names, self.commit)
        except CalibrationError as exc:
            self._tries += 1
            if self._tries % 100 == 1:
                log.warning("table of %d boxes not found yet: %s", len(self.names), exc)
        else:
            self._found(boxes)
            log.info("found the %d boxes: %s", len(self.names), self.fields)


VisionTable = PaperTable | OptionsTable


def vision_table(
    calibration: Path | None, params: Path | None, schedule: OptionsSchedule | None
) -> tuple[VisionTable, str]:
    """The table for the option count, and where its boxes come from (for the log).

    Two options: `load_layout`'s. More: a calibration file's boxes when it has one per option;
    else found by colour, with the commit line of the file (the paper's), the params or SPEC.
    """
    if schedule is None:
        layout, origin = load_layout(calibration, params)
        return PaperTable(layout), origin
    names = schedule.names
    if calibration is None:
        layout, origin = load_layout(None, params)
        return OptionsTable(names, layout.commit), f"colours in the frames, commit from {origin}"
    try:
        return OptionsTable(names, CommitLine(), load_boxes(calibration, names)), str(calibration)
    except MissingBoxError as exc:  # the paper's file, say: its commit line, boxes by colour
        log.info("%s; finding the %d boxes by colour", exc, len(names))
    return OptionsTable(names, load_commit(calibration)), f"colours in the frames, {calibration}"


class VisionService:
    """Wires a Capture and a HandTracker to the rig's vision keys, for the table of its options."""

    def __init__(
        self,
        node: Node,
        capture: Capture,
        tracker: HandTracker,
        table: VisionTable,
        *,
        frames_hz: float = 2.0,
        frame_width: int = 320,
    ) -> None:
        self.node = node
        self.capture = capture
        self.tracker = tracker
        self.table = table
        self.frame_width = frame_width
        self.pub_hand = HandPublisher(node, lossless=capture.lossless)
        self.pub_layout = node.publisher("vision/layout")
        self.pub_frame = node.publisher("vision/frame") if frames_hz > 0 else None
        self._layout_key = node.keys.topic("vision/layout")
        self._queryable = node.session.declare_queryable(self._layout_key, self._on_layout_query)
        self._latest: tuple[Frame, TrackResult] | None = None
        self._shown = -1
        self.published = 0
        self.detected = 0
        self.exit_code = 0
        self._last_report = (time.monotonic(), 0, 0)
        node.every(1.0, self.publish_layout)
        if frames_hz > 0:
            node.every(1.0 / frames_hz, self.publish_frame)
        node.every(10.0, self.report)

    # -- hot path (tracking thread) ------------------------------------------------------------

    def process(self, frame: Frame) -> TrackResult:
        """Track one frame and publish its hand pose, stamped with the frame's seq and t_ns.

        A table still to be found looks for its boxes in the frame first.
        """
        self.table.look(frame.image)
        result = self.tracker.track(frame.image)
        self.pub_hand.put(frame, result, self.tracker.name)
        self.detected += result.detected
        self.published += 1
        self._latest = (frame, result)
        return result

    def loop(self) -> None:
        """Track frames until the source ends, fails or the node stops; then stop the node."""
        stop = self.node.stop
        try:
            while not stop.is_set():
                frame = self.capture.next(timeout=0.5)
                if frame is None:
                    if self.capture.ended:
                        break
                    continue
                self.process(frame)
        except CaptureError as exc:
            log.error("%s", exc)
            self.exit_code = 1
        except Exception:  # best effort at shutdown: the session may close under a last put
            if not stop.is_set():
                log.exception("vision: tracking loop failed")
                self.exit_code = 1
        finally:
            stop.set()

    # -- low-rate ticks (node thread) ----------------------------------------------------------

    def publish_layout(self, now_ns: int) -> None:
        """The boxes and commit line, latched by republishing every second (once known)."""
        fields = self.table.fields
        if fields is not None:
            self.pub_layout.put(t_ns=now_ns, **fields)

    def _on_layout_query(self, query: zenoh.Query) -> None:
        fields = self.table.fields
        if fields is None:  # not found yet: no answer, as nothing is published
            return
        msg = self.pub_layout.cls(seq=self.pub_layout.seq, t_ns=self.node.clock.now_ns(), **fields)
        query.reply(self._layout_key, m.encode(msg))

    def publish_frame(self, now_ns: int) -> None:
        """The newest tracked frame, downscaled with boxes and hand drawn, for the monitor."""
        latest = self._latest
        if self.pub_frame is None or latest is None or latest[0].seq == self._shown:
            return
        frame, result = latest
        jpeg, w, h = monitor_jpeg(frame.image, self.table.layout, result,
                                  width=self.frame_width, names=self.table.names)
        self.pub_frame.put(
            t_ns=frame.t_ns,
            jpeg=jpeg,
            width=w,
            height=h,
            hand_seq=frame.seq,
            detected=result.detected,
        )
        self._shown = frame.seq

    def report(self, now_ns: int) -> None:
        """One status line: tracked rate, detection rate, frames dropped."""
        t0, n0, d0 = self._last_report
        t, n, d = time.monotonic(), self.published, self.detected
        if t - t0 < 1.0:  # the first tick runs at start: nothing to report yet
            return
        self._last_report = (t, n, d)
        if n == n0:
            log.warning("vision: no frame from %s for %.0f s", self.capture.source.label, t - t0)
            return
        log.info(
            "vision: %.1f fps tracked, hand seen in %.0f%%, %d frames dropped so far",
            (n - n0) / (t - t0),
            100.0 * (d - d0) / (n - n0),
            self.capture.dropped,
        )

    def wait_for_subscriber(self, timeout_s: float) -> bool:
        """Wait until someone subscribes to the hand key (replays of files); True if so."""
        probe = self.node.session.declare_publisher(self.pub_hand.key)
        try:
            deadline = time.monotonic() + timeout_s
            # zenoh's stub types `matching_status` as a bool; it is a MatchingStatus (zenoh 1.x)
            while not probe.matching_status.matching:  # type: ignore[attr-defined]  # stub bug
                if time.monotonic() > deadline or self.node.stop.wait(0.02):
                    return False
            return True
        finally:
            probe.undeclare()


def load_layout(calibration: Path | None, params: Path | None) -> tuple[TableLayout, str]:
    """The table geometry: calibration file, else the params file's layout, else SPEC's."""
    if calibration is not None:
        return load_calibration(calibration), str(calibration)
    if params is not None:
        return load_with_options(params)[0].layout, f"{params} [layout]"
    return TableLayout(), "SPEC defaults"


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod vision`."""
    p = fabric_parser(
        "nod vision",
        "Capture a camera, track the hand, publish vision/hand, vision/layout and "
        "vision/frame. `nod vision calibrate --help` writes the calibration file.",
    )
    add_clock_args(p)
    add_params_arg(p)
    g = p.add_argument_group("capture")
    g.add_argument(
        "--source",
        required=True,
        help="camera index (0), video file, stream URL (rtsp://, http://) or 'sim'",
    )
    g.add_argument("--width", type=int_in(1, 8192), default=None,
                   help="frame width to ask the camera for")
    g.add_argument("--height", type=int_in(1, 8192), default=None,
                   help="frame height to ask the camera for")
    g.add_argument("--fps", type=float, default=None, help="camera rate to ask for (Hz)")
    g.add_argument("--realtime", action="store_true", help="play a file at its own frame rate")
    g.add_argument("--loop", action="store_true", help="play a file (or sim) again at its end")
    g.add_argument("--stall", type=float, default=3.0, help="reopen a camera silent this long (s)")
    t = p.add_argument_group("tracking")
    t.add_argument("--tracker", choices=sorted(TRACKERS), default="aruco", help="hand tracker")
    t.add_argument("--dictionary", default="DICT_4X4_50", help="ArUco dictionary (aruco, sim)")
    t.add_argument("--marker-id", type=int_in(0, 4095), default=None,
                   help="the hand's marker id (any)")
    t.add_argument("--model-complexity", type=int_in(0, 1), default=1,
                   help="mediapipe model: 0 or 1")
    t.add_argument("--min-confidence", type=float, default=0.5, help="mediapipe confidence")
    t.add_argument("--calibration", type=Path, default=None, help="boxes + commit line (TOML)")
    o = p.add_argument_group("output")
    o.add_argument("--frames-key-hz", type=float, default=2.0, help="monitor JPEG rate (0: off)")
    o.add_argument("--frame-width", type=int_in(16, 8192), default=320,
                   help="monitor JPEG width (px)")
    o.add_argument(
        "--wait-for-subscriber",
        type=float,
        default=0.0,
        metavar="S",
        help="wait up to S seconds for a hand-key subscriber before reading (file replays)",
    )
    add_options_arg(p)
    p.add_argument("-v", "--verbose", action="store_true")
    return p


def _opener(node: Node | None, params: CaptureParams):
    """The frame opener: OpenCV, or the node's own session for a `zenoh:` source."""
    if node is None:
        return open_video

    def open_zenoh(source, _params):
        return ZenohCamera(node.session, node.keys.topic(str(source.target)), params.timeout_s)

    return open_zenoh


def quiet_opencv(cv: Any = cv2) -> None:
    """Let OpenCV print errors only, on any OpenCV this project meets.

    OpenCV 5 (opencv-python-headless here) has `cv2.utils.logging.setLogLevel`; OpenCV 4.x (which
    pyproject.toml still allows) has no `cv2.utils.logging`, only the top-level `cv2.setLogLevel`
    taking the same numbers (cv::utils::logging, 2 = ERROR).
    """
    logging_module = getattr(getattr(cv, "utils", None), "logging", None)
    if logging_module is not None:
        logging_module.setLogLevel(logging_module.LOG_LEVEL_ERROR)
    elif hasattr(cv, "setLogLevel"):
        cv.setLogLevel(_CV_LOG_LEVEL_ERROR)


_CV_LOG_LEVEL_ERROR = 2  # cv::utils::logging::LOG_LEVEL_ERROR, in OpenCV 4 and 5 alike


def main(argv: list[str] | None = None) -> int:
    """Run `nod vision` (or `nod vision calibrate …`); 0 at a file's end or on a signal."""
    args_list = list(sys.argv[1:] if argv is None else argv)
    if args_list[:1] == ["calibrate"]:
        from services.vision.calibration import main as calibrate_main

        return calibrate_main(args_list[1:])
    args = build_parser().parse_args(args_list)
    setup_logging(args.verbose)
    if not args.verbose:  # OpenCV's own warnings repeat on every reopen attempt; ours say it all
        quiet_opencv()
    node: Node | None = None
    try:
        if not 0 <= args.frames_key_hz <= 30:
            raise ValueError(f"--frames-key-hz must be in [0, 30], got {args.frames_key_hz}")
        if not 16 <= args.frame_width <= 1920:
            raise ValueError(f"--frame-width must be in [16, 1920], got {args.frame_width}")
        _, schedule = load_with_options(args.params, args.options)
        table, layout_origin = vision_table(args.calibration, args.params, schedule)
        params = CaptureParams(
            width=args.width,
            height=args.height,
            fps=args.fps,
            realtime=args.realtime,
            loop=args.loop,
            stall_s=args.stall,
        )
        source = parse_source(args.source)
        fabric = Fabric.from_args(args)
        node = Node("vision", fabric, retry_s=math.inf) if source.kind == "zenoh" else None
        capture = Capture(source, params, opener=_opener(node, params))
        info = capture.open()
        options = TrackerOptions(
            dictionary=args.dictionary,
            marker_id=args.marker_id,
            model_complexity=args.model_complexity,
            min_confidence=args.min_confidence,
        )
        tracker = make_tracker(args.tracker, options)
    except (
        ValueError,
        OSError,
        ConnectionError,
        ConfigError,
        CaptureError,
        TrackerUnavailableError,
    ) as exc:
        print(f"nod vision: {exc}", file=sys.stderr)
        if "capture" in locals():
            capture.close()
        if node is not None:
            node.close()
        return 2
    log.info("%s: %s", capture.source.label, info.describe(params))
    log.info("tracker %s; layout from %s: %s", tracker.name, layout_origin, table.fields)
    try:
        node = node or Node("vision", fabric, retry_s=math.inf)
    except (ValueError, OSError, ConnectionError) as exc:
        capture.close()
        tracker.close()
        return fail("nod vision", exc)
    service = VisionService(
        node, capture, tracker, table, frames_hz=args.frames_key_hz, frame_width=args.frame_width
    )
    if args.wait_for_subscriber > 0 and not service.wait_for_subscriber(args.wait_for_subscriber):
        log.warning("no subscriber on %s yet; starting anyway", service.pub_hand.key)
    capture.start(node.clock.now_ns)
    worker = threading.Thread(target=service.loop, name="vision-track", daemon=True)
    worker.start()
    try:
        node.run()
    finally:
        stuck = stop_threads(node, capture, worker, tracker)
    log.info(
        "vision: %d hand poses published (%d with a hand)", service.published, service.detected
    )
    if stuck:
        exit_now(service.exit_code, stuck)
    return service.exit_code


EXIT_JOIN_S = 1.5  # how long the threads get to stop; under the signals' 2 s forced exit


def stop_threads(
    node: Node,
    capture: Capture,
    worker: threading.Thread,
    tracker: HandTracker,
    timeout: float = EXIT_JOIN_S,
) -> list[threading.Thread]:
    """Stop and join every thread of the service within `timeout` s; those still running.

    The capture readers (each releases its source on its own thread), the tracking thread (then
    the tracker is closed here, nobody uses it any more) and the node's heartbeat, which puts on
    zenoh and drops its zenoh publisher as it ends. Nothing waits a fixed time: each join ends
    when its thread does.
    """
    deadline = time.monotonic() + timeout
    node.stop.set()  # the tracking loop and the heartbeat end; run() has closed the session
    stuck = capture.close(timeout)
    worker.join(max(0.0, deadline - time.monotonic()))
    if worker.is_alive():  # still inside the tracker: closing it under its feet is worse
        stuck.append(worker)
    else:
        tracker.close()
    # The abort this module's exit path had (see exit_now) was the heartbeat ending during
    # finalization: `Node.close` joins it; one still running is stuck like the others.
    return stuck + node.join_threads(deadline - time.monotonic())


def exit_now(code: int, stuck: list[threading.Thread]) -> NoReturn:
    """Exit with `code` at once, skipping the interpreter's finalization: threads still run.

    A thread still inside OpenCV (a read nothing can interrupt: a stalled camera or stream),
    mediapipe or zenoh when the interpreter finalizes is ended by pthread_exit the moment it
    returns to Python and asks for the GIL (CPython < 3.14). That forced unwind crosses the
    binding's catch-all (cv2's `catch (...)`, PyO3's `catch_unwind`), which swallows it, and
    glibc aborts the whole process: "FATAL: exception not rethrown", SIGABRT instead of our
    exit status. `os._exit` ends the process without finalization, so it cannot abort; nothing is
    lost: the session is closed, the logs and standard streams are flushed here.
    """
    log.warning(
        "vision: %s did not stop in time; exiting without finalization",
        ", ".join(t.name for t in stuck),
    )
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # closed or broken: nothing more to say
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    raise SystemExit(main())
