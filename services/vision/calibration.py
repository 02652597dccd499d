"""Buzzer boxes and the commit line: the calibration file and `nod vision calibrate`.

The calibration file is TOML in normalised image coordinates (x right, y down, [0, 1]) with the
shape of `TableLayout` — the same tables as `[layout]` in a params file:

    [red]
    x1 = 0.72
    y1 = 0.12
    x2 = 0.86
    y2 = 0.26
    [blue]
    x1 = 0.14
    ...
    [commit]
    y = 0.45
    start_side = "below"

A table of N boxes has one table per option, named by the option (`[red]`, `[blue]`,
`[green]`, …), and the same `[commit]`: the paper's file is its two-option case, read by both
`load_calibration` (the paper's `TableLayout`) and `load_boxes` (any option names, in their
order). The order of the tables in the file does not matter: box j is the session's option j.

`nod vision calibrate` writes it from a saved frame (or one grabbed from `--source`): each box
either from two opposite corners given as numbers — the "clicks", in pixels of the frame unless
`--units norm` — or, when not given, by finding the red and blue buzzers by colour (HSV
thresholds; the largest blob of each colour, its bounding box grown by `--margin`). With
`--names red,blue,green` it writes a table of N boxes, each found by its option's colour
(`services.scene.option_colours`; `find_option_boxes`). A preview image with the boxes drawn
shows the result on a machine without a screen.
"""

from __future__ import annotations

import argparse
import datetime as dt
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from services.core.cli import Parser, fail, int_in
from services.core.config import ConfigError, from_mapping, load_toml
from services.model.geometry import COLOURS, Box, CommitLine, OptionsLayout, TableLayout
from services.scene.option_colours import colour_of

log = logging.getLogger("nod.vision.calibrate")

HsvRange = tuple[tuple[int, int, int], tuple[int, int, int]]


class CalibrationError(ValueError):
    """The boxes cannot be found or the numbers given are invalid; the text says what to do."""


@dataclass(frozen=True, slots=True)
class HsvThresholds:
    """Colour ranges of the buzzers in OpenCV's HSV (H in [0, 180), S and V in [0, 255])."""

    red: tuple[HsvRange, ...] = (((0, 120, 70), (10, 255, 255)), ((170, 120, 70), (180, 255, 255)))
    blue: tuple[HsvRange, ...] = (((100, 120, 50), (130, 255, 255)),)
    min_area: float = 0.002  # smallest blob accepted, as a fraction of the image area


def load_calibration(path: str | Path) -> TableLayout:
    """Read a calibration file (or a params file's `[layout]` table) into a TableLayout."""
    data = load_toml(path)
    if set(data) == {"layout"}:
        data = data["layout"]
    try:
        return from_mapping(TableLayout, data, "calibration")
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


class MissingBoxError(ConfigError):
    """A calibration file has no box for some option: it may still give the commit line."""


def _tables(path: str | Path) -> dict[str, Any]:
    data = load_toml(path)
    return data["layout"] if set(data) == {"layout"} else data


def load_commit(path: str | Path) -> CommitLine:
    """The commit line of a calibration file, whatever boxes it holds."""
    try:
        return from_mapping(CommitLine, _tables(path).get("commit", {}), "calibration.commit")
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def load_boxes(path: str | Path, names: tuple[str, ...]) -> OptionsLayout:
    """The boxes of options `names` (box j is option j) and the commit line of a calibration file.

    Any file of boxes by option name: the paper's red/blue file is the case `("red", "blue")`.
    A name without its table is refused (MissingBoxError) in one line naming the ones it has.
    """
    data = _tables(path)
    have = sorted(k for k, v in data.items() if k != "commit" and isinstance(v, dict))
    missing = [name for name in names if not isinstance(data.get(name), dict)]
    if missing:
        raise MissingBoxError(
            f"{path}: no box for option(s) {', '.join(missing)} (the file has {', '.join(have)}); "
            f"write one with `nod vision calibrate --names {','.join(names)}`"
        )
    try:
        boxes = tuple(from_mapping(Box, data[name], f"calibration.{name}") for name in names)
        return OptionsLayout(boxes, load_commit(path))
    except (ConfigError, ValueError) as exc:
        raise ConfigError(f"{path}: {exc}") from None


def load_table(path: str | Path) -> TableLayout | OptionsLayout:
    """Whatever table a calibration file holds (what `nod rig`'s preflight checks).

    The paper's red and blue are checked as `load_calibration` checks them (an unknown key
    refused); a file with other names holds N boxes by option name (`load_boxes`).
    """
    names = tuple(k for k, v in _tables(path).items() if k != "commit" and isinstance(v, dict))
    if set(names) <= {"red", "blue"}:
        return load_calibration(path)
    return load_boxes(path, names)


def dump_calibration(
    layout: TableLayout | OptionsLayout, note: str = "", names: tuple[str, ...] = COLOURS
) -> str:
    """The TOML text of a calibration (4 decimals: 0.1 px on a 1000 px image).

    A `TableLayout` is the paper's red and blue; an `OptionsLayout` writes box j as `names[j]`.
    """
    lines = [
        "# nod vision calibration: buzzer boxes [x1, y1]-[x2, y2] and the commit line y,",
        "# in normalised image coordinates (x right, y down, both in [0, 1]).",
    ]
    if note:
        lines.append(f"# {note}")
    if isinstance(layout, TableLayout):
        named: tuple[tuple[str, Box], ...] = (("red", layout.red), ("blue", layout.blue))
    elif len(names) != layout.n_options:
        raise ValueError(f"{len(names)} names for a table of {layout.n_options} boxes")
    else:
        named = tuple(zip(names, layout.boxes, strict=True))
    for name, b in named:
        lines += ["", f"[{name}]"] + [
            f"{k} = {getattr(b, k):.4f}" for k in ("x1", "y1", "x2", "y2")
        ]
    lines += [
        "",
        "[commit]",
        f"y = {layout.commit.y:.4f}",
        f'start_side = "{layout.commit.start_side}"',
    ]
    return "\n".join(lines) + "\n"


def colour_mask(frame_bgr: np.ndarray, ranges: tuple[HsvRange, ...]) -> np.ndarray:
    """The pixels inside any of the HSV ranges, cleaned of speckle (uint8 0/255)."""
    hsv = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2HSV)
    mask = np.zeros(hsv.shape[:2], np.uint8)
    for lo, hi in ranges:
        mask |= cv2.inRange(hsv, np.array(lo, np.uint8), np.array(hi, np.uint8))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)
    return cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)


def find_colour_box(
    frame_bgr: np.ndarray, ranges: tuple[HsvRange, ...], min_area: float, margin: float = 0.0
) -> tuple[Box | None, int]:
    """The bounding box (normalised, grown by `margin`) of the largest blob, and its area in px."""
    h, w = frame_bgr.shape[:2]
    n, _labels, stats, _ = cv2.connectedComponentsWithStats(colour_mask(frame_bgr, ranges))
    if n <= 1:
        return None, 0
    i = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, bw, bh, area = (int(v) for v in stats[i])
    if area < min_area * w * h:
        return None, area
    box = Box(
        max(0.0, x / w - margin),
        max(0.0, y / h - margin),
        min(1.0, (x + bw) / w + margin),
        min(1.0, (y + bh) / h + margin),
    )
    return box, area


def detect_buzzer(
    frame_bgr: np.ndarray, colour: str, thresholds: HsvThresholds, margin: float = 0.0
) -> Box:
    """The box of the red or blue buzzer found by colour, or CalibrationError."""
    ranges = thresholds.red if colour == "red" else thresholds.blue
    box, area = find_colour_box(frame_bgr, ranges, thresholds.min_area, margin)
    if box is None:
        h, w = frame_bgr.shape[:2]
        need = int(thresholds.min_area * w * h)
        raise CalibrationError(
            f"no {colour} buzzer found by colour (largest {colour} area {area} px, need {need});"
            f" check the lighting, or give the box as corners with --{colour} X1,Y1,X2,Y2"
        )
    return box


def find_option_boxes(
    frame_bgr: np.ndarray, names: tuple[str, ...], commit: CommitLine,
    min_area: float = HsvThresholds().min_area, margin: float = 0.0,
) -> OptionsLayout:
    """The boxes of `names` (box j is option j), each found by its option's colour in one frame.

    The colours are `services.scene.option_colours`' (red and blue with the paper's ranges), the
    box the largest blob of that colour; a box not found, or two that overlap, is refused in one
    line.
    """
    boxes = []
    h, w = frame_bgr.shape[:2]
    for name in names:
        box, area = find_colour_box(frame_bgr, colour_of(name)[1], min_area, margin)
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


def box_from_numbers(text: str, width: int | None, height: int | None, colour: str) -> Box:
    """A box from two opposite corners "X1,Y1,X2,Y2" in pixels (with a size) or normalised."""
    try:
        x1, y1, x2, y2 = (float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise CalibrationError(f"--{colour} needs four numbers X1,Y1,X2,Y2, got {text!r}") from None
    if width is not None and height is not None:
        x1, x2, y1, y2 = x1 / width, x2 / width, y1 / height, y2 / height
    xs, ys = sorted((x1, x2)), sorted((y1, y2))
    if xs[0] < 0.0 or xs[1] > 1.0 or ys[0] < 0.0 or ys[1] > 1.0:
        raise CalibrationError(f"--{colour} {text!r} lies outside the image")
    if xs[0] == xs[1] or ys[0] == ys[1]:
        raise CalibrationError(f"--{colour} {text!r} is a line, not a box")
    return Box(xs[0], ys[0], xs[1], ys[1])


def calibrate(
    frame_bgr: np.ndarray | None,
    *,
    red: str | None = None,
    blue: str | None = None,
    units: str = "px",
    commit_y: float | None = None,
    start_side: str = "below",
    margin: float = 0.0,
    thresholds: HsvThresholds | None = None,
) -> tuple[TableLayout, str]:
    """The layout from given corners and/or colour detection; returns it and how it was found."""
    th = thresholds or HsvThresholds()
    size: tuple[int | None, int | None] = (None, None)
    if units == "px":
        if frame_bgr is None:
            raise CalibrationError("corners in pixels need the frame (--frame); or --units norm")
        size = (frame_bgr.shape[1], frame_bgr.shape[0])
    how: list[str] = []
    boxes: dict[str, Box] = {}
    for colour, given in (("red", red), ("blue", blue)):
        if given is not None:
            boxes[colour] = box_from_numbers(given, *size, colour)
            how.append(f"{colour} from corners")
        elif frame_bgr is None:
            raise CalibrationError(f"finding the {colour} buzzer by colour needs --frame")
        else:
            boxes[colour] = detect_buzzer(frame_bgr, colour, th, margin)
            how.append(f"{colour} by colour")
    commit = commit_line(frame_bgr, commit_y, units, start_side)
    if boxes["red"].contains(boxes["blue"].center) or boxes["blue"].contains(boxes["red"].center):
        raise CalibrationError("the red and blue boxes overlap; check the corners or the colours")
    layout = TableLayout(
        red=boxes["red"],
        blue=boxes["blue"],
        commit=commit,
    )
    for colour in ("red", "blue"):
        if not layout.commit.crossed(layout.box(colour).center):  # type: ignore[arg-type]
            log.warning("the %s box is on the participant's side of the commit line", colour)
    return layout, ", ".join(how)


def commit_line(
    frame_bgr: np.ndarray | None, commit_y: float | None, units: str, start_side: str
) -> CommitLine:
    """The commit line from `--commit-y` (pixels of the frame, or normalised) and its side."""
    y = CommitLine().y if commit_y is None else commit_y
    if commit_y is not None and units == "px":
        if frame_bgr is None:
            raise CalibrationError("--commit-y in pixels needs the frame; or --units norm")
        y = commit_y / frame_bgr.shape[0]
    if not 0.0 <= y <= 1.0:
        raise CalibrationError(f"--commit-y {commit_y} lies outside the image")
    return CommitLine(y=y, start_side=start_side)  # type: ignore[arg-type]


def grab_frame(source: str, skip: int = 10) -> np.ndarray:
    """One frame from a source, after `skip` frames (a camera's exposure settles)."""
    from services.vision.capture import Capture, CaptureError, parse_source

    cap = Capture(parse_source(source))
    try:
        cap.open()
        cap.start()
        frame = None
        for _ in range(skip + 1):
            got = cap.next(timeout=5.0)
            if got is None:
                break
            frame = got
        if frame is None:
            raise CaptureError(f"no frame from {source}")
        return frame.image
    finally:
        cap.close()


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod vision calibrate`."""
    p = Parser(
        prog="nod vision calibrate",
        description="Write the buzzer boxes and the commit line to a calibration file.",
    )
    src = p.add_mutually_exclusive_group()
    src.add_argument("--frame", type=Path, help="a saved camera frame (PNG/JPEG)")
    src.add_argument("--source", help="grab the frame from this source (device, file, URL)")
    p.add_argument("--save-frame", type=Path, help="with --source: also save the grabbed frame")
    p.add_argument("--red", metavar="X1,Y1,X2,Y2", help="red box corners (else found by colour)")
    p.add_argument("--blue", metavar="X1,Y1,X2,Y2", help="blue box corners (else by colour)")
    p.add_argument(
        "--units",
        choices=("px", "norm"),
        default="px",
        help="units of --red/--blue/--commit-y: pixels of the frame (default) or normalised",
    )
    p.add_argument("--commit-y", type=float, default=None, help="commit line y (default 0.45 norm)")
    p.add_argument(
        "--start-side",
        choices=("below", "above"),
        default="below",
        help="where the participant's hand starts relative to the commit line (default below)",
    )
    p.add_argument(
        "--names",
        metavar="A,B,C",
        help="a table of these options' boxes (3 or more, named by colour: red,blue,green), "
        "each found by its colour; the file then holds one box per name",
    )
    p.add_argument("--margin", type=float, default=0.0, help="grow colour boxes by this (norm)")
    p.add_argument("--min-saturation", type=int_in(0, 255), default=120,
                   help="HSV S threshold (0-255)")
    p.add_argument("--min-value", type=int_in(0, 255), default=60, help="HSV V threshold (0-255)")
    p.add_argument("-o", "--out", type=Path, default=Path("calibration.toml"), help="output file")
    p.add_argument("--preview", type=Path, help="write the frame with the boxes drawn here")
    return p


def _thresholds(sat: int, val: int) -> HsvThresholds:
    if not (0 <= sat <= 255 and 0 <= val <= 255):
        raise CalibrationError("--min-saturation and --min-value must be in [0, 255]")
    return HsvThresholds(
        red=(((0, sat, val), (10, 255, 255)), ((170, sat, val), (180, 255, 255))),
        blue=(((100, sat, val), (130, 255, 255)),),
    )


def main(argv: list[str] | None = None) -> int:
    """Run `nod vision calibrate`; 0 on success, 2 with one line on stderr otherwise."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        frame: np.ndarray | None = None
        origin = ""
        if args.frame is not None:
            frame = cv2.imread(str(args.frame), cv2.IMREAD_COLOR)
            if frame is None:
                raise CalibrationError(f"cannot read the image {args.frame}")
            origin = str(args.frame)
        elif args.source is not None:
            frame = grab_frame(args.source)
            origin = args.source
            if args.save_frame is not None:
                cv2.imwrite(str(args.save_frame), frame)
        layout: TableLayout | OptionsLayout
        names: tuple[str, ...] = COLOURS
        if args.names is not None:
            names, layout = _table_of_names(args, frame)
            how = "every box by colour"
        else:
            layout, how = calibrate(
                frame,
                red=args.red,
                blue=args.blue,
                units=args.units,
                commit_y=args.commit_y,
                start_side=args.start_side,
                margin=args.margin,
                thresholds=_thresholds(args.min_saturation, args.min_value),
            )
    except (CalibrationError, OSError, RuntimeError, ValueError) as exc:
        return fail("nod vision calibrate", exc)
    size = f" ({frame.shape[1]}x{frame.shape[0]})" if frame is not None else ""
    stamp = dt.datetime.now().isoformat(timespec="seconds")
    note = f"written {stamp} from {origin or 'numbers'}{size}: {how}"
    args.out.write_text(dump_calibration(layout, note, names))
    if args.preview is not None and frame is not None:
        from services.vision.overlay import draw_layout

        cv2.imwrite(str(args.preview), draw_layout(frame.copy(), layout, names))
    print(_summary(layout, args.out, names))
    return 0


def _table_of_names(
    args: argparse.Namespace, frame: np.ndarray | None
) -> tuple[tuple[str, ...], OptionsLayout]:
    """`--names`: the option names and their boxes, each found by its colour in the frame."""
    names = tuple(n.strip() for n in args.names.split(",") if n.strip())
    if len(names) < 2 or len(set(names)) != len(names):
        raise CalibrationError(f"--names needs two or more different names, got {args.names!r}")
    if args.red is not None or args.blue is not None:
        raise CalibrationError("--names finds every box by colour: drop --red and --blue")
    if frame is None:
        raise CalibrationError("finding the boxes by colour needs the frame (--frame or --source)")
    commit = commit_line(frame, args.commit_y, args.units, args.start_side)
    min_area = _thresholds(args.min_saturation, args.min_value).min_area
    return names, find_option_boxes(frame, names, commit, min_area, args.margin)


def _fmt(box: Box) -> str:
    return f"({box.x1:.3f}, {box.y1:.3f})-({box.x2:.3f}, {box.y2:.3f})"


def _summary(layout: TableLayout | OptionsLayout, out: Path, names: tuple[str, ...]) -> str:
    boxes = (layout.red, layout.blue) if isinstance(layout, TableLayout) else layout.boxes
    each = ", ".join(f"{name} {_fmt(box)}" for name, box in zip(names, boxes, strict=True))
    return f"wrote {out}: {each}, commit y = {layout.commit.y:.3f}"
