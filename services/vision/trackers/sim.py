"""The `sim` tracker: the ArUco marker of a rendered frame posed as a flat 21-landmark hand.

`SimTracker` (`--tracker sim`) stands in for the 21-landmark MediaPipe model on frames of the
synthetic camera (`services.scene`): it finds the marker and poses a flat 21-landmark hand
(MediaPipe order) on it — position, in-plane rotation and scale — so the rest of the loop sees
MediaPipe-shaped hands whose mean is the marker's centre, without the mediapipe environment.
"""

from __future__ import annotations

import math

import numpy as np

from services.model.geometry import HAND_TEMPLATE
from services.scene.markers import MARKER_PER_RADIUS, rotation
from services.vision.trackers import NOT_DETECTED, TrackResult, normalised
from services.vision.trackers.aruco import ArucoTracker


class SimTracker(ArucoTracker):
    """The marker posed as a flat 21-landmark hand (MediaPipe order): mean = marker centre.

    The same marker detection as the aruco tracker; only the landmarks it reports differ.
    """

    name = "sim"

    def track(self, frame_bgr: np.ndarray) -> TrackResult:
        """21 landmarks posed by the marker's position, rotation and size, or NOT_DETECTED."""
        corners = self.detector.corners(frame_bgr)
        if corners is None:
            return NOT_DETECTED
        centre = corners.mean(axis=0)
        top = corners[1] - corners[0]
        side = float(np.mean(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1)))
        rot = rotation(math.atan2(top[1], top[0]))
        pts = centre + (HAND_TEMPLATE * (side / MARKER_PER_RADIUS)) @ rot.T
        h, w = frame_bgr.shape[:2]
        return TrackResult(True, normalised(pts, w, h))
