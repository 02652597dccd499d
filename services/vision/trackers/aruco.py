"""The `aruco` tracker: an ArUco marker on the back of the hand, with OpenCV alone.

Landmarks are the marker's four corners (clockwise from its top-left as printed), so the
published centre — the mean of the landmarks, by the contract — is the mean of the corners: the
marker's centre (exactly for a marker seen square-on, within a fraction of a pixel otherwise).
The corners rather than corners + centre: a centre landmark would add no information and would
weigh the mean toward itself under perspective. Four landmarks also make the experiment's
"pressed" test (any landmark inside a box) fire when the marker's edge enters a box.

With `marker_id` unset, any marker of the dictionary is the hand; when several are seen the
largest (nearest the camera) wins, deterministically.
"""

from __future__ import annotations

import cv2
import numpy as np

from services.scene.markers import aruco_dictionary
from services.vision.trackers import (
    NOT_DETECTED,
    HandTracker,
    TrackerOptions,
    TrackResult,
    normalised,
)


class MarkerDetector:
    """Finds the hand's marker in a frame: its 4 corners in pixels, or None."""

    def __init__(self, dictionary: str = "DICT_4X4_50", marker_id: int | None = None) -> None:
        self.dictionary_name = dictionary
        self.marker_id = marker_id
        params = cv2.aruco.DetectorParameters()
        # Sub-pixel corners: a few hundred µs per marker for a centre stable to ~0.1 px.
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        self._detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)

    def corners(self, frame_bgr: np.ndarray) -> np.ndarray | None:
        """The chosen marker's corners as a (4, 2) float array in pixels, or None."""
        gray = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2GRAY) if frame_bgr.ndim == 3 else frame_bgr
        found, ids, _rejected = self._detector.detectMarkers(gray)
        if ids is None or len(found) == 0:
            return None
        best: np.ndarray | None = None
        best_area = -1.0
        for quad, marker in zip(found, ids.ravel(), strict=True):
            if self.marker_id is not None and int(marker) != self.marker_id:
                continue
            pts = quad.reshape(4, 2).astype(np.float64)
            area = abs(float(cv2.contourArea(pts.astype(np.float32))))
            if area > best_area:
                best, best_area = pts, area
        return best


class ArucoTracker(HandTracker):
    """The hand is the marker: landmarks = its 4 corners, normalised."""

    name = "aruco"

    def __init__(self, options: TrackerOptions | None = None) -> None:
        opts = options or TrackerOptions()
        self.detector = MarkerDetector(opts.dictionary, opts.marker_id)

    def track(self, frame_bgr: np.ndarray) -> TrackResult:
        """The marker's corners in one frame, or NOT_DETECTED."""
        corners = self.detector.corners(frame_bgr)
        if corners is None:
            return NOT_DETECTED
        h, w = frame_bgr.shape[:2]
        return TrackResult(True, normalised(corners, w, h))
