"""A synthetic overhead camera: rendered frames of the rig with a hand carrying an ArUco marker.

`SceneRenderer` draws what the overhead camera of the rig sees: the table, the red and blue
buzzer boxes of a `TableLayout`, the commit line, and a hand with an ArUco marker on its back at
a given centre and in-plane angle. The marker is composited with exact sub-pixel geometry, so
the known centre is the ground truth for the trackers (tests, benchmark, `nod run --sim
--render`). `HandPath` scripts a deterministic hand movement; `RenderedSource` serves it with the
`cv2.VideoCapture` interface, which is what `nod vision --source sim` reads; `write_video`
stores one as a real video file.

Shared by the sim service (`nod sim --render` is the camera) and the vision service (`--source
sim`, the `sim` tracker), so neither imports the other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from services.model.geometry import HAND_TEMPLATE, Box, TableLayout
from services.scene.markers import MARKER_PER_RADIUS, aruco_dictionary, rotation

_PALM = (0, 1, 5, 9, 13, 17)  # wrist, thumb CMC and the four MCPs
_FINGERS = ((1, 2, 3, 4), (5, 6, 7, 8), (9, 10, 11, 12), (13, 14, 15, 16), (17, 18, 19, 20))
_SKIN = (150, 175, 215)  # BGR, hue ~12°, saturation ~30 %: neither "red" nor "blue" in HSV
_RED = (40, 40, 200)
_BLUE = (190, 90, 30)
_TABLE = (128, 132, 124)



@dataclass(frozen=True)
class HandPath:
    """A scripted hand: waypoints (t [s], x, y) joined by smooth (cosine-eased) moves.

    `None` in place of (x, y) hides the hand from that waypoint until the next one.
    """

    waypoints: tuple[tuple[float, float, float] | tuple[float, None, None], ...]
    wobble: float = 0.15  # amplitude (rad) of a slow in-plane rotation of the hand

    @property
    def duration(self) -> float:
        """The time of the last waypoint, s."""
        return float(self.waypoints[-1][0])

    def at(self, t: float) -> tuple[float, float, float] | None:
        """(x, y, angle) of the hand at time t, or None while it is hidden."""
        wps = self.waypoints
        i = max((k for k in range(len(wps)) if wps[k][0] <= t), default=0)
        t0, x0, y0 = wps[i]
        if x0 is None or y0 is None:
            return None
        angle = self.wobble * math.sin(0.9 * t)
        if i + 1 >= len(wps) or wps[i + 1][1] is None:
            return (float(x0), float(y0), angle)
        t1, x1, y1 = wps[i + 1]
        assert x1 is not None and y1 is not None
        s = 0.5 - 0.5 * math.cos(math.pi * min(1.0, (t - t0) / max(t1 - t0, 1e-9)))
        return (x0 + (x1 - x0) * s, y0 + (y1 - y0) * s, angle)

    def sample(self, n: int, fps: float) -> list[tuple[float, float, float] | None]:
        """The hand at frames 0..n-1 of a camera at `fps`."""
        return [self.at(k / fps) for k in range(n)]


def demo_path(layout: TableLayout | None = None) -> HandPath:
    """Rest at the start, reach the red box, come back, reach the blue box, come back (7 s)."""
    lay = layout or TableLayout()
    (rx, ry), (bx, by) = lay.red.center, lay.blue.center
    start = (0.5, 0.85)
    return HandPath(
        (
            (0.0, *start),
            (0.4, *start),
            (1.9, rx, ry),
            (2.2, rx, ry),
            (3.7, *start),
            (5.2, bx, by),
            (5.5, bx, by),
            (7.0, *start),
        )
    )


@dataclass
class SceneRenderer:
    """Renders the rig's overhead view: table, buzzer boxes, commit line, hand with marker."""

    layout: TableLayout = field(default_factory=TableLayout)
    width: int = 640
    height: int = 480
    marker_size: float = 0.06  # marker side as a fraction of the image width
    marker_id: int = 0
    dictionary: str = "DICT_4X4_50"
    noise: float = 0.0  # Gaussian pixel noise (grey levels) added to every frame
    seed: int = 0  # seeds the table's texture
    # A table of N boxes instead of the layout's red and blue (each box with its BGR paint:
    # `services.scene.option_colours.painted_boxes`); the commit line stays the layout's.
    options: tuple[tuple[Box, tuple[int, int, int]], ...] | None = None

    def __post_init__(self) -> None:
        if not (16 <= self.width <= 8192 and 16 <= self.height <= 8192):
            raise ValueError(f"frame size {self.width}x{self.height} out of range")
        self._rng = np.random.default_rng(self.seed)
        self._background = self._draw_background()
        side_px = self.marker_size * self.width
        cells = aruco_dictionary(self.dictionary).markerSize + 2  # bits + the black border
        self._k = max(2, round(side_px / cells))
        marker = cv2.aruco.generateImageMarker(
            aruco_dictionary(self.dictionary), self.marker_id, cells * self._k
        )
        self._patch = cv2.copyMakeBorder(marker, *(self._k,) * 4, cv2.BORDER_CONSTANT, value=255)
        self._scale = side_px / (cells * self._k)
        self._noise = np.empty((self.height, self.width, 3), np.int16)

    @property
    def marker_px(self) -> float:
        """The marker's side in pixels."""
        return self.marker_size * self.width

    def _draw_background(self) -> np.ndarray:
        w, h = self.width, self.height
        img = np.empty((h, w, 3), np.uint8)
        img[:] = _TABLE
        grain = cv2.resize(self._rng.normal(0, 6, (h // 16 + 1, w // 16 + 1)), (w, h))
        img = np.clip(img + grain[..., None], 0, 255).astype(np.uint8)
        boxes = self.options or ((self.layout.red, _RED), (self.layout.blue, _BLUE))
        for box, colour in boxes:
            p1 = (round(box.x1 * w), round(box.y1 * h))
            p2 = (round(box.x2 * w) - 1, round(box.y2 * h) - 1)
            cv2.rectangle(img, p1, p2, colour, -1)
            centre = ((p1[0] + p2[0]) // 2, (p1[1] + p2[1]) // 2)
            radius = max(2, min(p2[0] - p1[0], p2[1] - p1[1]) // 3)
            bright = tuple(min(255, int(c * 1.25)) for c in colour)
            cv2.circle(img, centre, radius, bright, -1, cv2.LINE_AA)  # the buzzer button
        y = round(self.layout.commit.y * h)
        cv2.line(img, (0, y), (w - 1, y), (225, 225, 225), 2)
        return img

    def hand_landmarks(self, x: float, y: float, angle: float = 0.0) -> np.ndarray:
        """The rendered hand's 21 landmarks (normalised, MediaPipe order); mean = (x, y)."""
        radius = self.marker_px / MARKER_PER_RADIUS
        pts = (HAND_TEMPLATE * radius) @ rotation(angle).T
        return np.column_stack([x + pts[:, 0] / self.width, y + pts[:, 1] / self.height])

    def render(self, hand: tuple[float, float, float] | tuple[float, float] | None) -> np.ndarray:
        """One BGR frame with the hand at normalised (x, y[, angle]), or no hand for None."""
        img = self._background.copy()
        if hand is not None:
            x, y = hand[0], hand[1]
            angle = hand[2] if len(hand) > 2 else 0.0
            self._draw_hand(img, x, y, angle)
            self._draw_marker(img, x, y, angle)
        if self.noise > 0:  # OpenCV's RNG: 5x faster than numpy's here, though not seeded
            cv2.randn(self._noise, np.zeros(3), np.full(3, float(self.noise)))
            img = cv2.add(img, self._noise, dtype=cv2.CV_8U)
        return img

    def _draw_hand(self, img: np.ndarray, x: float, y: float, angle: float) -> None:
        shift = 4  # sub-pixel drawing: coordinates in 1/16 px
        px = (self.hand_landmarks(x, y, angle) * (self.width, self.height) - 0.5) * (1 << shift)
        pts = np.round(px).astype(np.int32)
        thick = max(2, round(0.3 * self.marker_px / MARKER_PER_RADIUS))
        cv2.fillPoly(img, [pts[list(_PALM)]], _SKIN, cv2.LINE_AA, shift)
        for finger in _FINGERS:
            chain = pts[[0, *finger]] if finger[0] == 1 else pts[list(finger)]
            cv2.polylines(img, [chain], False, _SKIN, thick, cv2.LINE_AA, shift)

    def _draw_marker(self, img: np.ndarray, x: float, y: float, angle: float) -> None:
        n = self._patch.shape[0]
        centre_patch = (n - 1) / 2.0
        centre_img = np.array([x * self.width - 0.5, y * self.height - 0.5])
        rot = rotation(angle) * self._scale
        offset = centre_img - rot @ np.array([centre_patch, centre_patch])
        half = 0.75 * n * self._scale + 2
        x0, y0 = (max(0, int(c - half)) for c in centre_img)
        x1 = min(self.width, int(centre_img[0] + half) + 1)
        y1 = min(self.height, int(centre_img[1] + half) + 1)
        if x1 <= x0 or y1 <= y0:
            return
        affine = np.hstack([rot, (offset - (x0, y0)).reshape(2, 1)])
        size = (x1 - x0, y1 - y0)
        warped = cv2.warpAffine(self._patch, affine, size, flags=cv2.INTER_LINEAR)
        alpha = cv2.warpAffine(np.full_like(self._patch, 255), affine, size, flags=cv2.INTER_LINEAR)
        a = (alpha.astype(np.float32) / 255.0)[..., None]
        roi = img[y0:y1, x0:x1]
        roi[:] = (roi * (1.0 - a) + warped[..., None].astype(np.float32) * a).astype(np.uint8)


class RenderedSource:
    """A scripted hand on the rendered table, served like a `cv2.VideoCapture` (read/get/…)."""

    def __init__(self, renderer: SceneRenderer, path: HandPath, fps: float = 30.0) -> None:
        self.renderer = renderer
        self.fps = fps
        self.truth = path.sample(int(round(path.duration * fps)) + 1, fps)
        self._pos = 0
        self._open = True

    def isOpened(self) -> bool:
        """True until released."""
        return self._open

    def grab(self) -> bool:
        """Advance to the next frame; False after the last one."""
        if not self._open or self._pos >= len(self.truth):
            return False
        self._pos += 1
        return True

    def retrieve(self) -> tuple[bool, np.ndarray | None]:
        """Render the frame grabbed last."""
        if not self._open or self._pos == 0:
            return False, None
        return True, self.renderer.render(self.truth[self._pos - 1])

    def read(self) -> tuple[bool, np.ndarray | None]:
        """grab() then retrieve()."""
        return self.retrieve() if self.grab() else (False, None)

    def get(self, prop: int) -> float:
        """The few properties a capture reports: size, fps, frame count and position."""
        values = {
            cv2.CAP_PROP_FRAME_WIDTH: self.renderer.width,
            cv2.CAP_PROP_FRAME_HEIGHT: self.renderer.height,
            cv2.CAP_PROP_FPS: self.fps,
            cv2.CAP_PROP_FRAME_COUNT: len(self.truth),
            cv2.CAP_PROP_POS_FRAMES: self._pos,
        }
        return float(values.get(prop, 0.0))

    def set(self, prop: int, value: float) -> bool:
        """Settings are fixed by the renderer; nothing can be changed."""
        return False

    def release(self) -> None:
        """Close the source."""
        self._open = False


def write_video(
    path: str | Path,
    renderer: SceneRenderer,
    hand_path: HandPath,
    fps: float = 30.0,
    frames: int | None = None,
) -> list[tuple[float, float, float] | None]:
    """Render a scripted hand into an MJPG video file; return the hand of every frame."""
    n = int(round(hand_path.duration * fps)) + 1 if frames is None else frames
    truth = hand_path.sample(n, fps)
    size = (renderer.width, renderer.height)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), fps, size)
    if not writer.isOpened():
        raise OSError(f"cannot write an MJPG video to {path}")
    try:
        for hand in truth:
            writer.write(renderer.render(hand))
    finally:
        writer.release()
    return truth
