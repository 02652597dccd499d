"""A rendered table of N boxes, and vision finding each option's box by its colour."""

from __future__ import annotations

import pytest

from services.model.geometry import CommitLine, OptionsLayout
from services.scene.option_colours import painted_boxes
from services.scene.render import SceneRenderer
from services.vision.calibration import CalibrationError, find_option_boxes

NAMES = ("red", "blue", "green", "yellow")


@pytest.mark.parametrize("n", [2, 3, 4])
def test_vision_finds_every_rendered_box_within_a_pixel(n: int) -> None:
    layout, names = OptionsLayout.row(n), NAMES[:n]
    renderer = SceneRenderer(options=painted_boxes(names, layout), noise=2.0, seed=n)
    found = find_option_boxes(renderer.render((0.5, 0.8)), names, CommitLine())
    px = (1 / renderer.width, 1 / renderer.height)
    for got, want in zip(found.boxes, layout.boxes, strict=True):
        for a, b, unit in zip((got.x1, got.y1, got.x2, got.y2),
                              (want.x1, want.y1, want.x2, want.y2), px * 2, strict=True):
            assert abs(a - b) <= 1.5 * unit


def test_a_box_out_of_view_or_an_unknown_colour_is_one_line() -> None:
    layout = OptionsLayout.row(3)
    two = SceneRenderer(options=painted_boxes(("red", "blue", "green"), layout)[:2])
    with pytest.raises(CalibrationError, match="no green box found by colour"):
        find_option_boxes(two.render(None), ("red", "blue", "green"), CommitLine())
    with pytest.raises(ValueError, match="no colour is known for option 'mauve'"):
        painted_boxes(("red", "blue", "mauve"), layout)
