"""Camera capture: a device, a video file, a stream URL or the rendered scene, via OpenCV.

A capture thread reads frames, stamps each one (`t_ns`, the node clock) right after the grab
and numbers it (`seq` counts frames read, so a consumer sees drops as gaps), and puts it into a
`deque(maxlen=1)`: the consumer always gets the newest frame (Keelson's capture pattern). A file
(or the rendered scene) played as fast as possible is lossless instead — the reader waits until
the consumer took the frame — since nothing is gained by skipping frames of a recording;
`realtime=True` plays it at its own rate, live-like.

A live source that disappears (read fails) or stalls (no frame for `stall_s`) is reopened with
exponential backoff; meanwhile no frames come, so the hand key goes stale and the safety
watchdogs act. The capture logs one line when it loses the source and one when it is back. A
stalled read cannot be interrupted, so its thread is abandoned and a fresh one reopens the
source; the old one exits when its read returns.

Each reader releases its source on its own thread (an OpenCV capture is never used from two).
`close()` stops and joins them within one timeout and returns those still running: a reader
blocked in a read nothing can interrupt (a stalled camera or stream; a source with an
`interrupt()`, as `ZenohCamera`, is woken), which its owner must not leave running into the
interpreter's finalization (see `services.vision.service.exit_now`).

A file that cannot be opened or decoded raises `CaptureError` at `open()`; a file that ends
before the frame count its header declares is reported as truncated (`next()` raises).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Protocol

import cv2
import numpy as np

log = logging.getLogger("nod.vision.capture")

SourceKind = Literal["device", "file", "url", "sim", "zenoh"]


class CaptureError(RuntimeError):
    """A source cannot be opened or read; the text says which and what to check."""


@dataclass(frozen=True, slots=True)
class Source:
    """Where frames come from: a device index, a file path, a stream URL or "sim"."""

    kind: SourceKind
    target: int | str

    @property
    def label(self) -> str:
        """How logs name the source."""
        names = {
            "device": "camera",
            "file": "video file",
            "url": "stream",
            "sim": "rendered scene",
            "zenoh": "frames on key",
        }
        return f"{names[self.kind]} {self.target}" if self.kind != "sim" else names["sim"]

    @property
    def live(self) -> bool:
        """A camera or stream: frames happen in real time and can be missed."""
        return self.kind in ("device", "url", "zenoh")


def parse_source(text: str) -> Source:
    """Read `--source`: a device index, a stream URL, `sim`, `zenoh:TOPIC`, or else a file.

    `zenoh:TOPIC` reads JPEG frames from the rig's key TOPIC (e.g. `zenoh:sim/camera`).
    """
    text = text.strip()
    if not text:
        raise ValueError("--source is empty; give a device index, a video file or a URL")
    if text.isdigit():
        return Source("device", int(text))
    if text == "sim":
        return Source("sim", "sim")
    if text.startswith("zenoh:"):
        return Source("zenoh", text.removeprefix("zenoh:"))
    if "://" in text:
        return Source("url", text)
    return Source("file", text)


@dataclass(frozen=True, slots=True)
class CaptureParams:
    """How to read a source."""

    width: int | None = None  # requested frame width, px (devices; reported if not honoured)
    height: int | None = None  # requested frame height, px (devices)
    fps: float | None = None  # requested camera rate (devices); playback rate for --realtime
    realtime: bool = False  # files: deliver at the file's frame rate, not as fast as possible
    loop: bool = False  # files and the rendered scene: start again at the end (reopens)
    backoff_s: float = 0.5  # first wait before reopening a lost source, s (then doubles)
    backoff_max_s: float = 8.0  # longest wait between reopen attempts, s
    stall_s: float = 3.0  # a live source without a frame for this long is reopened, s
    timeout_s: float = 10.0  # open/read timeout handed to the stream backend (URLs), s

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if v is not None and not 16 <= v <= 8192:
                raise ValueError(f"--{name} must be in [16, 8192] px, got {v}")
        if self.fps is not None and not 0 < self.fps <= 1000:
            raise ValueError(f"--fps must be in (0, 1000], got {self.fps}")
        if not 0 < self.backoff_s <= self.backoff_max_s:
            raise ValueError("backoff must satisfy 0 < backoff_s <= backoff_max_s")
        if self.stall_s <= 0 or self.timeout_s <= 0:
            raise ValueError("stall_s and timeout_s must be > 0")


@dataclass(frozen=True, slots=True)
class Frame:
    """One captured frame: BGR pixels, its number and its capture time (ns)."""

    image: np.ndarray
    seq: int
    t_ns: int


@dataclass(frozen=True, slots=True)
class SourceInfo:
    """What the source really gives (as opposed to what was asked)."""

    width: int
    height: int
    fps: float  # 0 when the backend does not know
    frame_count: int  # files: frames declared by the container; 0 for live sources

    def describe(self, params: CaptureParams) -> str:
        """One line: what we got, and what was asked when it differs."""
        got = f"{self.width}x{self.height} @ {self.fps:.3g} fps"
        if self.frame_count > 0:
            got += f", {self.frame_count} frames"
        asked = []
        wanted = (params.width, params.height)
        if None not in wanted and wanted != (self.width, self.height):
            asked.append(f"{params.width}x{params.height}")
        if params.fps is not None and abs(params.fps - self.fps) > 0.5:
            asked.append(f"{params.fps:.3g} fps")
        return got + (f" (asked {' @ '.join(asked)})" if asked else "")


class VideoLike(Protocol):
    """The part of `cv2.VideoCapture` the capture uses (tests inject fakes)."""

    def isOpened(self) -> bool: ...  # noqa: D102
    def read(self) -> tuple[bool, np.ndarray | None]: ...  # noqa: D102
    def grab(self) -> bool: ...  # noqa: D102
    def retrieve(self) -> tuple[bool, np.ndarray | None]: ...  # noqa: D102
    def get(self, prop: int) -> float: ...  # noqa: D102
    def set(self, prop: int, value: float) -> bool: ...  # noqa: D102
    def release(self) -> None: ...  # noqa: D102


Opener = Callable[[Source, CaptureParams], VideoLike]


def open_video(source: Source, params: CaptureParams) -> VideoLike:
    """Open a source with OpenCV (or the renderer for "sim") and apply the requested settings."""
    if source.kind == "sim":
        from services.scene.render import RenderedSource, SceneRenderer, demo_path

        renderer = SceneRenderer(width=params.width or 640, height=params.height or 480)
        return RenderedSource(renderer, demo_path(renderer.layout), fps=params.fps or 30.0)
    if source.kind == "zenoh":
        raise ValueError("a zenoh frame source needs the service's session (nod vision opens it)")
    if source.kind == "url":
        ms = int(params.timeout_s * 1000)
        opts = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, ms]
        return cv2.VideoCapture(str(source.target), cv2.CAP_FFMPEG, opts)
    if source.kind == "file":
        return cv2.VideoCapture(str(source.target))
    cap = cv2.VideoCapture(int(source.target))
    if cap.isOpened():
        if params.width is not None:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, params.width)
        if params.height is not None:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, params.height)
        if params.fps is not None:
            cap.set(cv2.CAP_PROP_FPS, params.fps)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # newest frame, not a queue of old ones
    return cap


class Capture:
    """Reads a source on its own thread; `next()` hands out the newest frame."""

    def __init__(
        self, source: Source, params: CaptureParams | None = None, *, opener: Opener = open_video
    ) -> None:
        self.source = source
        self.params = params or CaptureParams()
        self._opener = opener
        self._slot: deque[Frame] = deque(maxlen=1)
        self._cv = threading.Condition()
        self._stop = threading.Event()
        self._now_ns: Callable[[], int] = time.time_ns
        self._gen = 0  # the generation of the active reader; stale readers exit
        self._cap: VideoLike | None = None
        self._first: np.ndarray | None = None
        self._reading = False  # the active reader is between reads (stall watch applies)
        self._progress = time.monotonic()  # last frame (or open) of the active reader
        self._threads: list[threading.Thread] = []
        self._using: dict[int, VideoLike] = {}  # each reader's open source, by generation
        self._detail = ""  # why a file ended early
        self.info: SourceInfo | None = None
        self.seq = 0  # frames read so far (the next frame's number)
        self.dropped = 0  # frames replaced in the slot before anyone took them
        self.reopens = 0  # successful reopen cycles after a loss or a loop
        self.ended = False  # no more frames will come (file end, error or close)
        self.error: str | None = None

    @property
    def lossless(self) -> bool:
        """Whether the reader waits for the consumer (recordings played as fast as possible)."""
        return not self.source.live and not self.params.realtime

    # -- opening -------------------------------------------------------------------------------

    def open(self) -> SourceInfo:
        """Open the source and decode one frame, or raise CaptureError saying why not."""
        self._cap, self._first = self._open_once()
        return self.info  # type: ignore[return-value]  # set by _open_once

    def _open_once(self) -> tuple[VideoLike, np.ndarray]:
        src = self.source
        if src.kind == "file" and not Path(str(src.target)).is_file():
            raise CaptureError(f"video file not found: {src.target}")
        try:
            cap = self._opener(src, self.params)
        except (cv2.error, OSError, ValueError) as exc:
            raise CaptureError(f"cannot open {src.label}: {exc}") from None
        if not cap.isOpened():
            cap.release()
            raise CaptureError(f"cannot open {src.label}: {self._hint()}")
        ok, image = cap.read()
        if not ok or image is None:
            cap.release()
            raise CaptureError(f"{src.label} opened but no frame could be decoded: {self._hint()}")
        h, w = image.shape[:2]
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0) if not src.live else 0
        self.info = SourceInfo(w, h, fps if fps > 0 else 0.0, max(count, 0))
        return cap, image

    def _hint(self) -> str:
        return {
            "file": "not a video OpenCV can decode, or damaged (check it with ffprobe)",
            "device": "is the camera plugged in and free? (ls /dev/video*; another program?)",
            "url": "is the stream up and the URL right? (try it with ffplay)",
            "sim": "the renderer failed",
            "zenoh": "is `nod sim --render` (or another frame publisher) running on this rig?",
        }[self.source.kind]

    # -- the reader ----------------------------------------------------------------------------

    def start(self, now_ns: Callable[[], int] = time.time_ns) -> None:
        """Start reading on a background thread (call `open()` first); stamps with `now_ns`."""
        if self._cap is None:
            raise RuntimeError("Capture.open() must succeed before start()")
        self._now_ns = now_ns
        self._spawn(self._cap, self._first)
        self._cap = self._first = None
        if self.source.live:
            watch = threading.Thread(target=self._watch, name="capture-watch", daemon=True)
            watch.start()
            self._threads.append(watch)

    def _spawn(self, cap: VideoLike | None, first: np.ndarray | None) -> None:
        with self._cv:
            self._gen += 1
            gen = self._gen
            self._reading = False
        t = threading.Thread(
            target=self._run, args=(gen, cap, first), name=f"capture-{gen}", daemon=True
        )
        t.start()
        self._threads.append(t)

    def _current(self, gen: int) -> bool:
        return gen == self._gen and not self._stop.is_set()

    def _run(self, gen: int, cap: VideoLike | None, first: np.ndarray | None) -> None:
        backoff, attempts, lost_at = self.params.backoff_s, 0, time.monotonic()
        if self.source.live:
            first = None  # the probe frame of open() is stale by now
        while self._current(gen):
            if cap is None:
                try:
                    cap, first = self._open_once()
                except CaptureError as exc:
                    attempts += 1
                    level = (
                        logging.WARNING if attempts == 1 or attempts % 20 == 0 else logging.DEBUG
                    )
                    log.log(level, "%s (attempt %d; retrying in %.2g s)", exc, attempts, backoff)
                    self._stop.wait(backoff)
                    backoff = min(2 * backoff, self.params.backoff_max_s)
                    continue
                if attempts or self.source.live:
                    log.info(
                        "%s back after %.1f s: %s",
                        self.source.label,
                        time.monotonic() - lost_at,
                        self.info.describe(self.params) if self.info else "",
                    )
                self.reopens += 1
                if self.source.live:
                    first = None
            with self._cv:  # before the first read: close() interrupts what it finds here
                self._using[gen] = cap
            outcome = self._pump(gen, cap, first)
            self._mark_progress(gen, reading=False)
            with self._cv:
                self._using.pop(gen, None)
            cap.release()
            cap, first = None, None
            if outcome == "stopped":
                return
            if outcome == "eof" and not self.params.loop:
                log.info("%s ended after %d frames", self.source.label, self.seq)
                self._finish(None)
                return
            if outcome == "truncated":
                self._finish(f"{self.source.label} is truncated or damaged: {self._detail}")
                return
            if outcome == "lost":
                log.warning(
                    "%s lost after frame %d; reopening with backoff (the hand key goes stale)",
                    self.source.label,
                    self.seq,
                )
                lost_at, attempts, backoff = time.monotonic(), 0, self.params.backoff_s
                self._stop.wait(backoff)

    def _pump(self, gen: int, cap: VideoLike, first: np.ndarray | None) -> str:
        """Read frames until the source fails: "eof", "lost", "truncated" or "stopped"."""
        pace = 0.0
        if self.params.realtime and not self.source.live:
            fps = self.params.fps or (self.info.fps if self.info else 0.0) or 30.0
            pace = 1.0 / fps
        start, n = time.monotonic(), 0
        self._mark_progress(gen, reading=True)
        image = first
        while self._current(gen):
            if pace and self._stop.wait(max(0.0, start + n * pace - time.monotonic())):
                return "stopped"
            if image is None:
                if not cap.grab():
                    break
                t_ns = self._now_ns()
                ok, image = cap.retrieve()
                if not ok or image is None:
                    break
            else:
                t_ns = self._now_ns()
            if not self._current(gen):
                return "stopped"
            self._deliver(gen, Frame(image, self.seq, t_ns))
            self._mark_progress(gen, reading=True)
            n += 1
            image = None
        if not self._current(gen):
            return "stopped"
        if self.source.live:
            return "lost"
        declared = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        if self.source.kind == "file" and declared > 0 and n + 1 < declared:
            self._detail = f"decoded {n} of the {declared} frames its header declares"
            return "truncated"
        return "eof"

    def _mark_progress(self, gen: int, *, reading: bool) -> None:
        if gen == self._gen:
            self._progress = time.monotonic()
            self._reading = reading

    def _deliver(self, gen: int, frame: Frame) -> None:
        with self._cv:
            if self.lossless:
                self._cv.wait_for(lambda: not self._slot or not self._current(gen))
            if not self._current(gen):
                return
            if self._slot:
                self.dropped += 1
            self._slot.append(frame)
            self.seq += 1
            self._cv.notify_all()

    def _watch(self) -> None:
        """Abandon a reader whose read blocks beyond `stall_s`; a fresh one reopens."""
        while not self._stop.wait(0.1):
            if self.ended:
                return
            idle = time.monotonic() - self._progress
            if self._reading and idle > self.params.stall_s:
                log.warning(
                    "%s stalled: no frame for %.1f s; reopening (the hand key goes stale)",
                    self.source.label,
                    idle,
                )
                self._progress = time.monotonic()
                self._spawn(None, None)

    def _finish(self, error: str | None) -> None:
        with self._cv:
            self.ended = True
            self.error = error
            self._cv.notify_all()

    # -- the consumer --------------------------------------------------------------------------

    def next(self, timeout: float = 0.5) -> Frame | None:
        """The newest frame not yet taken; None after `timeout` s or at the end.

        Raises CaptureError once the source ended with an error (a truncated file).
        """
        with self._cv:
            self._cv.wait_for(lambda: bool(self._slot) or self.ended, timeout)
            if self._slot:
                frame = self._slot.popleft()
                self._cv.notify_all()
                return frame
            if self.ended and self.error:
                raise CaptureError(self.error)
            return None

    def close(self, timeout: float = 2.0) -> list[threading.Thread]:
        """Stop the readers, join them and release the source (idempotent).

        Waits up to `timeout` s in all; returns the threads still running then: readers blocked
        in a read that cannot be interrupted (each releases its own source when its read
        returns). A source with an `interrupt()` (`ZenohCamera`) is woken from its read.
        """
        self._stop.set()
        with self._cv:
            self._cv.notify_all()  # a lossless reader waiting for the consumer
            using = list(self._using.values())
        for cap in using:  # a reader registering after this sees `_stop` before its first read
            interrupt = getattr(cap, "interrupt", None)
            if interrupt is not None:
                interrupt()
        deadline = time.monotonic() + timeout
        me = threading.current_thread()
        for t in self._threads:
            if t is not me:
                t.join(max(0.0, deadline - time.monotonic()))
        if self._cap is not None:  # opened, never started: ours to release
            self._cap.release()
            self._cap = None
        with self._cv:
            self.ended = True
            self._cv.notify_all()
        return [t for t in self._threads if t is not me and t.is_alive()]
