"""Drawing for people: the buzzer boxes, the commit line and the tracked hand on a frame.

Used for the monitor's small JPEG (`vision/frame`) and for the calibration preview image.
"""

from __future__ import annotations

import cv2
import numpy as np

from services.core.messages import MAX_BLOB_BYTES
from services.model.geometry import Box, OptionsLayout, TableLayout
from services.scene.option_colours import colour_of
from services.vision.trackers import TrackResult

_BOX_COLOURS = {"red": (0, 0, 255), "blue": (255, 64, 0)}
_LINE = (0, 220, 255)  # the commit line, yellow
_LANDMARK = (0, 255, 0)
_CENTRE = (255, 255, 255)


def _px(x: float, y: float, w: int, h: int) -> tuple[int, int]:
    return (round(x * w - 0.5), round(y * h - 0.5))


def draw_layout(
    img: np.ndarray, layout: TableLayout | OptionsLayout | None, names: tuple[str, ...] = ()
) -> np.ndarray:
    """Outline the boxes in their colours and draw the commit line, in place.

    The paper's `TableLayout` in its own red and blue; an `OptionsLayout`'s box j in the paint
    of option `names[j]` (`services.scene.option_colours`); None (a table not found yet): nothing.
    """
    if layout is None:
        return img
    h, w = img.shape[:2]
    thick = max(1, w // 320)
    named: tuple[tuple[Box, tuple[int, int, int]], ...]
    if isinstance(layout, TableLayout):
        named = tuple((layout.box(c), _BOX_COLOURS[c]) for c in ("red", "blue"))
    else:
        named = tuple((b, colour_of(n)[0]) for n, b in zip(names, layout.boxes, strict=True))
    for box, bgr in named:
        p1, p2 = _px(box.x1, box.y1, w, h), _px(box.x2, box.y2, w, h)
        cv2.rectangle(img, p1, p2, bgr, thick, cv2.LINE_AA)
    y = round(layout.commit.y * h - 0.5)
    cv2.line(img, (0, y), (w - 1, y), _LINE, thick, cv2.LINE_AA)
    return img


def draw_hand(img: np.ndarray, result: TrackResult) -> np.ndarray:
    """Mark the landmarks (green dots) and the centre (white cross), in place."""
    if not result.detected:
        return img
    h, w = img.shape[:2]
    r = max(2, w // 200)
    for x, y in result.landmarks:
        cv2.circle(img, _px(x, y, w, h), r, _LANDMARK, -1, cv2.LINE_AA)
    c = result.center
    if c is not None:
        cv2.drawMarker(img, _px(c[0], c[1], w, h), _CENTRE, cv2.MARKER_CROSS, 4 * r, 2)
    return img


def monitor_jpeg(
    frame_bgr: np.ndarray,
    layout: TableLayout | OptionsLayout | None,
    result: TrackResult,
    width: int = 320,
    quality: int = 70,
    max_bytes: int = MAX_BLOB_BYTES,
    names: tuple[str, ...] = (),
) -> tuple[bytes, int, int]:
    """A downscaled frame with boxes and hand drawn, as JPEG bytes; returns (jpeg, w, h).

    `layout` and `names` as `draw_layout`'s.

    The quality steps down until the JPEG fits `max_bytes` (the message's limit).
    """
    h0, w0 = frame_bgr.shape[:2]
    w = max(16, min(width, w0))
    h = max(16, round(h0 * w / w0))
    small = cv2.resize(frame_bgr, (w, h), interpolation=cv2.INTER_AREA)
    draw_hand(draw_layout(small, layout, names), result)
    q = quality
    while True:
        ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, q])
        if not ok:
            raise ValueError("JPEG encoding failed")
        data = buf.tobytes()
        if len(data) <= max_bytes or q <= 10:
            break
        q -= 15
    if len(data) > max_bytes:
        raise ValueError(f"a {w}x{h} JPEG needs {len(data)} bytes > {max_bytes}; lower the width")
    return data, w, h
