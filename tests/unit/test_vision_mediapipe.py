"""MediaPipe Hands (`--tracker mediapipe`) on a real photograph of a hand.

The photo is `tests/fixtures/hand/hand_on_table.jpg` (OpenCV's documentation, Apache-2.0 AND
BSD-3-Clause; tests/fixtures/hand/SOURCE.md): an open hand on a grey table, 640×480. Where the
hand is was measured once by colour, independently of any tracker (SOURCE.md), and is written
below. Skipped without the `mediapipe` extra (`scripts/setup-env --mediapipe`).
"""

from pathlib import Path

import cv2
import numpy as np
import pytest

from services.scene.render import SceneRenderer
from services.vision.trackers import TrackerOptions, make_tracker

pytest.importorskip(
    "mediapipe", reason="the mediapipe extra is not installed (scripts/setup-env --mediapipe)"
)

HAND_JPG = Path(__file__).parents[1] / "fixtures" / "hand" / "hand_on_table.jpg"
W, H = 640, 480
# The hand's bounding box in the photo, pixels x1, y1, x2, y2 (inclusive), from its skin-coloured
# blob (SOURCE.md): it reaches the left edge (the wrist leaves the image there) and the top edge
# (the thumb's tip).
HAND_BOX = (0, 0, 549, 454)
MARGIN = 0.02  # normalised: a fingertip's landmark may sit just outside the blob


def _photo() -> np.ndarray:
    img = cv2.imread(str(HAND_JPG))
    assert img is not None and img.shape == (H, W, 3), f"cannot read {HAND_JPG}"
    return img


def _inside(point, box_px, margin=0.0) -> bool:
    x1, y1, x2, y2 = box_px
    x, y = point
    return (
        (x1 + 0.5) / W - margin <= x <= (x2 + 0.5) / W + margin
        and (y1 + 0.5) / H - margin <= y <= (y2 + 0.5) / H + margin
    )


@pytest.mark.parametrize("complexity", [0, 1])
def test_the_real_hand_is_found_with_21_landmarks_where_it_is(complexity):
    photo = _photo()
    with make_tracker("mediapipe", TrackerOptions(model_complexity=complexity)) as tracker:
        results = [tracker.track(photo) for _ in range(5)]  # detection, then tracking
    for res in results:
        assert res.detected and len(res.landmarks) == 21
        assert _inside(res.center, HAND_BOX)
        wrist, *others = res.landmarks  # MediaPipe order: the wrist first
        assert all(_inside(p, HAND_BOX, MARGIN) for p in others)
        # the wrist is beyond the photo's left edge: MediaPipe places it at or past that edge
        assert wrist[0] < 0.05 and HAND_BOX[1] / H <= wrist[1] <= HAND_BOX[3] / H
        # the centre is the mean of the landmarks (SPEC §2), not MediaPipe's own box
        assert res.center == pytest.approx(tuple(np.mean(res.landmarks, axis=0)))


def test_the_hand_pasted_onto_the_table_is_followed_wherever_it_is():
    """The photo at half size on the rendered table, at three places: the centre moves with it."""
    half = cv2.resize(_photo(), (W // 2, H // 2), interpolation=cv2.INTER_AREA)
    table = SceneRenderer(width=W, height=H, noise=2.0).render(None)
    box = tuple(v // 2 for v in HAND_BOX)
    offsets = ((40, 200), (300, 60), (160, 120))
    relative = []
    for ox, oy in offsets:
        frame = table.copy()
        frame[oy : oy + H // 2, ox : ox + W // 2] = half
        with make_tracker("mediapipe", TrackerOptions(model_complexity=0)) as tracker:
            res = [tracker.track(frame) for _ in range(3)][-1]
        assert res.detected and len(res.landmarks) == 21
        pasted = (box[0] + ox, box[1] + oy, box[2] + ox, box[3] + oy)
        assert _inside(res.center, pasted), (res.center, pasted)
        relative.append((res.center[0] - ox / W, res.center[1] - oy / H))
    # translation: the centre relative to the pasted photo is the same at every place
    assert np.ptp(np.array(relative), axis=0).max() < 0.01


def test_no_hand_on_the_empty_table():
    renderer = SceneRenderer(width=W, height=H, noise=2.0)
    with make_tracker("mediapipe", TrackerOptions(model_complexity=1)) as tracker:
        for _ in range(5):
            res = tracker.track(renderer.render(None))
            assert not res.detected and res.landmarks == () and res.center is None
        # and the hand is found again when it comes into view
        assert tracker.track(_photo()).detected
