"""Hand trackers behind one small interface: `HandTracker.track(frame_bgr) -> TrackResult`.

A tracker turns one BGR camera frame into the hand's landmarks in normalised image coordinates
(x right, y down, [0, 1] across the image; SPEC §2). The hand's centre is, by the contract, the
mean of its landmarks, so a tracker only reports landmarks and `TrackResult.center` derives it.
A hand that is not seen is `detected=False` with no landmarks — never a made-up position.

Backends (chosen with `nod vision --tracker`), imported lazily so that `aruco` and `sim` never
pay for, or depend on, mediapipe:

- `aruco`     an ArUco marker on the back of the hand; landmarks = the marker's 4 corners.
- `sim`       the marker posed as a 21-landmark hand (MediaPipe order), for rendered frames.
- `mediapipe` MediaPipe Hands, the paper's 21-landmark model (the optional `mediapipe` extra).
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from services.model.device import Scoped

Point = tuple[float, float]
TRACKERS: dict[str, str] = {
    "aruco": "services.vision.trackers.aruco:ArucoTracker",
    "sim": "services.vision.trackers.sim:SimTracker",
    "mediapipe": "services.vision.trackers.mediapipe:MediapipeTracker",
}


class TrackerUnavailableError(RuntimeError):
    """A tracker backend cannot run in this environment; the text says how to get it."""


@dataclass(frozen=True, slots=True)
class TrackResult:
    """One frame's hand: its landmarks (normalised), or nothing when not detected."""

    detected: bool
    landmarks: tuple[Point, ...] = ()

    def __post_init__(self) -> None:
        if self.detected != bool(self.landmarks):
            raise ValueError("a detected hand needs landmarks; an undetected one has none")

    @property
    def center(self) -> Point | None:
        """The hand centre: the mean of the landmarks (SPEC §2), or None when not detected."""
        if not self.landmarks:
            return None
        n = len(self.landmarks)
        return (sum(p[0] for p in self.landmarks) / n, sum(p[1] for p in self.landmarks) / n)


NOT_DETECTED = TrackResult(False)


def normalised(points_px: np.ndarray, width: int, height: int) -> tuple[Point, ...]:
    """Pixel coordinates (OpenCV: pixel centres at integers) to normalised coordinates.

    The image spans [-0.5, width - 0.5] in OpenCV's pixel coordinates and [0, 1] normalised.
    """
    pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
    xs = (pts[:, 0] + 0.5) / width
    ys = (pts[:, 1] + 0.5) / height
    return tuple((float(x), float(y)) for x, y in zip(xs, ys, strict=True))


class HandTracker(Scoped, ABC):
    """A hand tracker: one BGR frame in, one TrackResult out. Usable as a context manager."""

    name: ClassVar[str] = "tracker"

    @abstractmethod
    def track(self, frame_bgr: np.ndarray) -> TrackResult:
        """The hand in one frame (H×W×3 uint8, BGR)."""

    def close(self) -> None:
        """Release the backend's resources (models, sessions); idempotent."""
        return None

    def _on_exit(self) -> None:
        self.close()


@dataclass(frozen=True, slots=True)
class TrackerOptions:
    """Settings shared by the backends (each uses the ones that concern it)."""

    dictionary: str = "DICT_4X4_50"  # ArUco dictionary name of cv2.aruco (aruco, sim)
    marker_id: int | None = None  # the hand's marker id; None = any (the largest seen)
    model_complexity: int = 1  # MediaPipe Hands model: 0 (lite, faster) or 1 (full)
    min_confidence: float = 0.5  # MediaPipe detection and tracking confidence


def make_tracker(name: str, options: TrackerOptions | None = None) -> HandTracker:
    """Build a tracker by name, importing its backend only now."""
    if name not in TRACKERS:
        raise ValueError(f"unknown tracker {name!r}; choose one of {sorted(TRACKERS)}")
    module_name, cls_name = TRACKERS[name].split(":")
    cls = getattr(importlib.import_module(module_name), cls_name)
    return cls(options or TrackerOptions())
