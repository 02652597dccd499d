"""Vision finds a table of N boxes: each option's box by its name's colour.

`services.vision.calibration` finds the paper's red and blue buzzers by colour (HSV); this
finds one box per option name with the colours of `services.scene.option_colours` (red and
blue with the same ranges), as the largest blob of that colour, and refuses in one line a box
it cannot find or two that overlap.
"""

from __future__ import annotations

import numpy as np

from services.model.geometry import CommitLine, OptionsLayout
from services.scene.option_colours import colour_of
from services.vision.calibration import CalibrationError, HsvThresholds, find_colour_box


def find_option_boxes(
    frame_bgr: np.ndarray, names: tuple[str, ...], commit: CommitLine,
    min_area: float = HsvThresholds().min_area,
) -> OptionsLayout:
    """The boxes of `names` (box j is option j) found by colour in one frame."""
    boxes = []
    h, w = frame_bgr.shape[:2]
    for name in names:
        box, area = find_colour_box(frame_bgr, colour_of(name)[1], min_area)
        if box is None:
            raise CalibrationError(
                f"no {name} box found by colour (largest {name} area {area} px, need "
                f"{int(min_area * w * h)}); check the lighting and that every box is in view"
            )
        boxes.append(box)
    for i, a in enumerate(boxes):
        for j in range(i + 1, len(boxes)):
            if a.contains(boxes[j].center) or boxes[j].contains(a.center):
                raise CalibrationError(f"the {names[i]} and {names[j]} boxes overlap")
    return OptionsLayout(tuple(boxes), commit)
