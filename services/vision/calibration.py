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

`nod vision calibrate` writes it from a saved frame (or one grabbed from `--source`): each box
either from two opposite corners given as numbers — the "clicks", in pixels of the frame unless
`--units norm` — or, when not given, by finding the red and blue buzzers by colour (HSV
thresholds; the largest blob of each colour, its bounding box grown by `--margin`). A preview
image with the boxes drawn shows the result on a machine without a screen.
"""

from __future__ import annotations

import argparse
import datetime as dt
import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from services.core.cli import Parser, fail, int_in
from services.core.config import ConfigError, from_mapping, load_toml
from services.model.geometry import Box, CommitLine, TableLayout

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


def dump_calibration(layout: TableLayout, note: str = "") -> str:
    """The TOML text of a calibration (4 decimals: 0.1 px on a 1000 px image)."""
    lines = [
        "# nod vision calibration: buzzer boxes [x1, y1]-[x2, y2] and the commit line y,",
        "# in normalised image coordinates (x right, y down, both in [0, 1]).",
    ]
    if note:
        lines.append(f"# {note}")
    for name in ("red", "blue"):
        b: Box = getattr(layout, name)
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
    y = CommitLine().y if commit_y is None else commit_y
    if commit_y is not None and units == "px":
        y = commit_y / size[1]  # type: ignore[operator]
    if not 0.0 <= y <= 1.0:
        raise CalibrationError(f"--commit-y {commit_y} lies outside the image")
    if boxes["red"].contains(boxes["blue"].center) or boxes["blue"].contains(boxes["red"].center):
        raise CalibrationError("the red and blue boxes overlap; check the corners or the colours")
    layout = TableLayout(
        red=boxes["red"],
        blue=boxes["blue"],
        commit=CommitLine(y=y, start_side=start_side),  # type: ignore[arg-type]
    )
    for colour in ("red", "blue"):
        if not layout.commit.crossed(layout.box(colour).center):  # type: ignore[arg-type]
            log.warning("the %s box is on the participant's side of the commit line", colour)
    return layout, ", ".join(how)


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
    except (CalibrationError, OSError, RuntimeError) as exc:
        return fail("nod vision calibrate", exc)
    size = f" ({frame.shape[1]}x{frame.shape[0]})" if frame is not None else ""
    stamp = dt.datetime.now().isoformat(timespec="seconds")
    note = f"written {stamp} from {origin or 'numbers'}{size}: {how}"
    args.out.write_text(dump_calibration(layout, note))
    if args.preview is not None and frame is not None:
        from services.vision.overlay import draw_layout

        cv2.imwrite(str(args.preview), draw_layout(frame.copy(), layout))
    print(_summary(layout, args.out))
    return 0


def _fmt(box: Box) -> str:
    return f"({box.x1:.3f}, {box.y1:.3f})-({box.x2:.3f}, {box.y2:.3f})"


def _summary(layout: TableLayout, out: Path) -> str:
    red, blue, y = _fmt(layout.red), _fmt(layout.blue), layout.commit.y
    return f"wrote {out}: red {red}, blue {blue}, commit y = {y:.3f}"
