"""The colours of a table of N boxes: how each named option's box is drawn and found.

One place for both sides of the camera path over N options: the renderer paints option j's
box in its name's BGR colour (`services.scene.render.SceneRenderer.options`), and vision finds
it by that colour's HSV range (`services.vision.calibration.find_option_boxes`) and draws it in
that paint on the monitor's frame. The paper's red and blue are `services.scene.render`'s and
`services.vision.calibration.HsvThresholds`' own values, so a red or blue box of three is drawn
and found exactly as the paper's two.
"""

from __future__ import annotations

from services.model.geometry import Box, OptionsLayout

BGR = tuple[int, int, int]
HsvRange = tuple[tuple[int, int, int], tuple[int, int, int]]

# BGR paint (red and blue: the renderer's _RED and _BLUE) and OpenCV HSV ranges (H in [0, 180))
COLOURS: dict[str, tuple[BGR, tuple[HsvRange, ...]]] = {
    "red": ((40, 40, 200), (((0, 120, 70), (10, 255, 255)), ((170, 120, 70), (180, 255, 255)))),
    "blue": ((190, 90, 30), (((100, 120, 50), (130, 255, 255)),)),
    "green": ((50, 170, 40), (((45, 120, 50), (80, 255, 255)),)),
    "yellow": ((30, 200, 220), (((22, 120, 70), (35, 255, 255)),)),
}


def colour_of(name: str) -> tuple[BGR, tuple[HsvRange, ...]]:
    """The paint and HSV ranges of an option's name, or a one-line error naming the known ones."""
    try:
        return COLOURS[name]
    except KeyError:
        raise ValueError(
            f"no colour is known for option {name!r} (known: {', '.join(COLOURS)}): name the "
            "options by colour for a rendered or camera-found table"
        ) from None


GREY_HEX = "#9e9e9e"


def hex_of(name: str) -> str:
    """An option's paint as a plot colour (#rrggbb); grey for a name without a colour."""
    if name not in COLOURS:
        return GREY_HEX
    b, g, r = COLOURS[name][0]
    return f"#{r:02x}{g:02x}{b:02x}"


def painted_boxes(names: tuple[str, ...], layout: OptionsLayout) -> tuple[tuple[Box, BGR], ...]:
    """Each option's box with its paint, for `SceneRenderer.options`."""
    if len(names) != layout.n_options:
        raise ValueError(f"{len(names)} names for a table of {layout.n_options} boxes")
    return tuple((box, colour_of(name)[0]) for name, box in zip(names, layout.boxes, strict=True))
