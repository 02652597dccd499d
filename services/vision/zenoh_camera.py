"""A camera on the fabric: JPEG frames from a Zenoh key, read like an OpenCV capture.

`nod sim --render` publishes the simulated scene's frames on `nod/<rig>/sim/camera`; `nod vision
--source zenoh:sim/camera` reads them through this class, so the whole vision path (decode,
tracking, press detection) runs in `nod run --sim --render` exactly as with a real camera. Any
network camera bridged onto a key the same way works too.
"""

from __future__ import annotations

import threading
from collections import deque

import cv2
import numpy as np
import zenoh

from services.core import messages as m


class ZenohCamera:
    """The newest frame of a key; `read()` waits for the next one (VideoLike protocol)."""

    def __init__(self, session: zenoh.Session, key: str, timeout_s: float = 10.0) -> None:
        self.key = key
        self.timeout_s = timeout_s
        self.bad = 0
        self._slot: deque[m.VisionFrame] = deque(maxlen=1)  # a late frame is replaced, not queued
        self._cv = threading.Condition()
        self._open = True
        self._interrupted = False  # `interrupt()`: every read fails from now on
        self._grabbed: m.VisionFrame | None = None
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            frame = m.decode(m.VisionFrame, sample.payload.to_bytes())
        except m.MessageError:
            self.bad += 1  # counted; the stall watch reopens if nothing good arrives
            return
        with self._cv:
            self._slot.append(frame)
            self._cv.notify_all()

    def isOpened(self) -> bool:  # noqa: D102 - OpenCV's VideoCapture protocol
        return self._open

    def grab(self) -> bool:
        """Wait (up to the timeout) for the next frame, like a camera's grab."""
        with self._cv:
            if not self._cv.wait_for(self._readable, self.timeout_s):
                return False
            if not self._open or self._interrupted:
                return False
            self._grabbed = self._slot.popleft()
            return True

    def _readable(self) -> bool:
        return bool(self._slot) or not self._open or self._interrupted

    def interrupt(self) -> None:
        """Wake a `grab()` waiting for a frame, and fail every later one (from any thread).

        `Capture.close()` calls it so the reader thread stops now, not at the read timeout; the
        reader still releases the camera itself.
        """
        with self._cv:
            self._interrupted = True
            self._cv.notify_all()

    def retrieve(self) -> tuple[bool, np.ndarray | None]:
        """Decode the grabbed frame."""
        frame, self._grabbed = self._grabbed, None
        if frame is None:
            return False, None
        image = cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_COLOR)
        return (image is not None), image

    def read(self) -> tuple[bool, np.ndarray | None]:
        """Grab and decode the next frame."""
        return self.retrieve() if self.grab() else (False, None)

    def get(self, prop: int) -> float:  # noqa: D102
        return 0.0

    def set(self, prop: int, value: float) -> bool:  # noqa: D102
        return False

    def release(self) -> None:  # noqa: D102
        with self._cv:
            if not self._open:
                return
            self._open = False
            self._cv.notify_all()
        self._sub.undeclare()
