"""Capture: sources, lossless files, pacing, clear errors, and reopening a vanished source."""

import logging
import os
import threading
import time

import cv2
import numpy as np
import pytest

from services.vision.capture import (
    Capture,
    CaptureError,
    CaptureParams,
    Source,
    SourceInfo,
    parse_source,
)

FAST = CaptureParams(backoff_s=0.01, backoff_max_s=0.05, stall_s=0.3)


def _write(path, frames=10, fps=30.0, value=0, size=(64, 48)):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, size)
    assert writer.isOpened()
    for k in range(frames):
        img = np.full((size[1], size[0], 3), value, np.uint8)
        cv2.putText(img, str(k), (5, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2)
        writer.write(img)
    writer.release()
    return path


def _drain(cap, limit=10_000, timeout=2.0):
    frames = []
    while len(frames) < limit and (frame := cap.next(timeout=timeout)) is not None:
        frames.append(frame)
    return frames


class FakeCamera:
    """A camera that gives `frames` frames, then fails — or blocks, when given an event."""

    def __init__(self, frames, block=None, value=0):
        self.left = frames
        self.block = block
        self.value = value
        self.released = False

    def isOpened(self):
        return True

    def grab(self):
        if self.left <= 0:
            if self.block is not None:
                self.block.wait()
            return False
        self.left -= 1
        time.sleep(0.002)  # a camera takes time to deliver
        return True

    def retrieve(self):
        return True, np.full((48, 64, 3), self.value, np.uint8)

    def read(self):
        return self.retrieve() if self.grab() else (False, None)

    def get(self, prop):
        return 30.0 if prop == cv2.CAP_PROP_FPS else 0.0

    def set(self, prop, value):
        return False

    def release(self):
        self.released = True


class ScriptedOpener:
    """Returns the scripted cameras in turn (None = the device is absent), then the last one."""

    def __init__(self, *cameras):
        self.cameras = list(cameras)
        self.opens = 0

    def __call__(self, source, params):
        self.opens += 1
        cam = self.cameras.pop(0) if len(self.cameras) > 1 else self.cameras[0]
        if cam is None:
            closed = FakeCamera(0)
            closed.isOpened = lambda: False
            return closed
        return cam


@pytest.mark.parametrize(
    ("text", "kind", "target"),
    [
        ("0", "device", 0),
        (" 2 ", "device", 2),
        ("rtsp://cam.lab/stream", "url", "rtsp://cam.lab/stream"),
        ("http://10.0.0.5:8080/video", "url", "http://10.0.0.5:8080/video"),
        ("sim", "sim", "sim"),
        ("videos/run 1.avi", "file", "videos/run 1.avi"),
    ],
)
def test_sources_are_parsed(text, kind, target):
    assert parse_source(text) == Source(kind, target)


def test_a_file_is_read_losslessly_with_seq_and_capture_time(tmp_path):
    video = _write(tmp_path / "a.avi", frames=12)
    cap = Capture(parse_source(str(video)))
    info = cap.open()
    assert (info.width, info.height, info.frame_count) == (64, 48, 12)
    t_before = time.time_ns()
    cap.start()
    time.sleep(0.1)  # a slow consumer still gets every frame of a recording
    frames = _drain(cap)
    cap.close()
    assert [f.seq for f in frames] == list(range(12))
    assert all(t_before <= a.t_ns <= b.t_ns for a, b in zip(frames, frames[1:], strict=False))
    assert cap.ended and cap.error is None and cap.dropped == 0


def test_realtime_plays_a_file_at_its_frame_rate(tmp_path):
    video = _write(tmp_path / "rt.avi", frames=11, fps=50.0)
    cap = Capture(parse_source(str(video)), CaptureParams(realtime=True))
    cap.open()
    start = time.monotonic()
    cap.start()
    frames = _drain(cap)
    elapsed = time.monotonic() - start
    cap.close()
    assert len(frames) == 11
    assert elapsed >= 0.18  # 10 frame periods of 20 ms


@pytest.mark.parametrize(
    ("content", "fragment"),
    [(None, "video file not found"), (b"not a video" * 50, "cannot open video file")],
)
def test_missing_or_unreadable_files_give_a_clear_error(tmp_path, content, fragment):
    path = tmp_path / "bad.avi"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(CaptureError, match=fragment):
        Capture(parse_source(str(path))).open()


def test_a_truncated_file_gives_a_clear_error_after_its_good_frames(tmp_path):
    video = _write(tmp_path / "full.avi", frames=40)
    data = video.read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[: len(data) // 2])
    cap = Capture(parse_source(str(cut)))
    cap.open()
    cap.start()
    frames = []
    with pytest.raises(CaptureError, match=r"truncated or damaged: decoded \d+ of the 40 frames"):
        while (frame := cap.next(timeout=2.0)) is not None:
            frames.append(frame)
    cap.close()
    assert 5 < len(frames) < 40


def test_a_looping_file_that_is_replaced_is_reopened_with_the_new_content(tmp_path):
    video = _write(tmp_path / "live.avi", frames=5, value=20)
    cap = Capture(parse_source(str(video)), CaptureParams(loop=True, backoff_s=0.01))
    cap.open()
    cap.start()
    first = _drain(cap, limit=5)
    _write(tmp_path / "next.avi", frames=5, value=200)
    os.replace(tmp_path / "next.avi", video)  # replaced while open: the next pass reads it
    later = _drain(cap, limit=20)
    cap.close()
    assert [f.seq for f in first] == list(range(5))
    assert [f.seq for f in later] == list(range(5, 25))  # seq keeps counting across passes
    assert first[0].image.mean() < 60 and later[-1].image.mean() > 150
    assert cap.reopens >= 2


def test_a_vanished_camera_is_reopened_with_backoff(caplog):
    caplog.set_level(logging.INFO, logger="nod.vision.capture")
    opener = ScriptedOpener(FakeCamera(6), None, None, FakeCamera(10_000, value=99))
    cap = Capture(parse_source("0"), FAST, opener=opener)
    cap.open()
    cap.start()
    frames = _drain(cap, limit=40)
    cap.close()
    assert len(frames) == 40  # it came back
    assert opener.opens >= 4  # first camera, two failed attempts, the new camera
    assert frames[-1].image.mean() == 99
    seqs = [f.seq for f in frames]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    assert "lost after frame" in caplog.text and "back after" in caplog.text


def test_a_stalled_camera_is_abandoned_and_reopened(caplog):
    stuck = threading.Event()
    opener = ScriptedOpener(FakeCamera(5, block=stuck), FakeCamera(10_000, value=7))
    cap = Capture(parse_source("0"), FAST, opener=opener)
    cap.open()
    cap.start()
    try:
        frames = _drain(cap, limit=20, timeout=3.0)
    finally:
        stuck.set()
        cap.close()
    assert len(frames) == 20
    assert frames[-1].image.mean() == 7
    assert "stalled" in caplog.text


def test_a_live_source_hands_out_the_newest_frame_and_counts_drops():
    cap = Capture(parse_source("0"), FAST, opener=ScriptedOpener(FakeCamera(400)))
    cap.open()
    cap.start()
    got = []
    while len(got) < 10 and (frame := cap.next(timeout=1.0)) is not None:
        got.append(frame)
        time.sleep(0.02)  # a consumer slower than the camera
    cap.close()
    gaps = [b.seq - a.seq for a, b in zip(got, got[1:], strict=False)]
    assert max(gaps) > 1 and cap.dropped > 0


def test_a_camera_that_cannot_open_at_start_is_an_error():
    with pytest.raises(CaptureError, match="camera 0.*plugged in"):
        Capture(parse_source("0"), FAST, opener=ScriptedOpener(None)).open()


def test_what_was_asked_and_what_was_got_are_reported():
    params = CaptureParams(width=1280, height=720, fps=60.0)
    line = SourceInfo(640, 480, 30.0, 0).describe(params)
    assert line == "640x480 @ 30 fps (asked 1280x720 @ 60 fps)"
    assert SourceInfo(640, 480, 30.0, 0).describe(CaptureParams()) == "640x480 @ 30 fps"
    with pytest.raises(ValueError, match="--width"):
        CaptureParams(width=5)
