"""Calibration: buzzers found by colour, boxes from clicks, the TOML file and the CLI."""

import cv2
import numpy as np
import pytest

from services.core.config import ConfigError
from services.model.geometry import Box, CommitLine, OptionsLayout, TableLayout
from services.scene.option_colours import painted_boxes
from services.scene.render import SceneRenderer
from services.vision.calibration import (
    CalibrationError,
    MissingBoxError,
    box_from_numbers,
    calibrate,
    dump_calibration,
    load_boxes,
    load_calibration,
    load_commit,
    load_table,
    main,
)
from services.vision.service import main as vision_main

MIRRORED = TableLayout(
    red=Box(0.10, 0.08, 0.30, 0.30), blue=Box(0.65, 0.10, 0.90, 0.28), commit=CommitLine(0.5)
)


def _close(a: Box, b: Box, tol: float) -> bool:
    pairs = zip((a.x1, a.y1, a.x2, a.y2), (b.x1, b.y1, b.x2, b.y2), strict=True)
    return max(abs(u - v) for u, v in pairs) < tol


@pytest.mark.parametrize("layout", [TableLayout(), MIRRORED])
def test_buzzers_are_found_by_colour(layout):
    frame = SceneRenderer(layout=layout, noise=3.0).render((0.5, 0.8))  # the hand is not a buzzer
    found, how = calibrate(frame, commit_y=layout.commit.y, units="norm")
    assert how == "red by colour, blue by colour"
    assert _close(found.red, layout.red, 2 / 480)
    assert _close(found.blue, layout.blue, 2 / 480)
    assert found.commit.y == layout.commit.y


def test_a_missing_buzzer_says_how_to_give_it_by_hand():
    frame = np.full((240, 320, 3), 128, np.uint8)
    cv2.rectangle(frame, (20, 20), (80, 80), (200, 60, 20), -1)  # blue only
    with pytest.raises(CalibrationError, match="no red buzzer.*--red X1,Y1,X2,Y2"):
        calibrate(frame)


def test_clicks_in_pixels_any_corner_order_become_normalised_boxes():
    frame = np.zeros((480, 640, 3), np.uint8)
    layout, how = calibrate(frame, red="550,125,460,58", blue="90,58,180,125", commit_y=216)
    assert how == "red from corners, blue from corners"
    assert layout.red == Box(460 / 640, 58 / 480, 550 / 640, 125 / 480)
    assert layout.blue.x1 == pytest.approx(90 / 640)
    assert layout.commit.y == pytest.approx(0.45)


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("1,2,3", "four numbers"),
        ("a,b,c,d", "four numbers"),
        ("0,0,700,10", "outside"),
        ("5,5,5,9", "a line"),
    ],
)
def test_bad_clicks_are_rejected(text, fragment):
    with pytest.raises(CalibrationError, match=fragment):
        box_from_numbers(text, 640, 480, "red")


def test_overlapping_boxes_are_rejected():
    with pytest.raises(CalibrationError, match="overlap"):
        calibrate(None, red="0.1,0.1,0.5,0.5", blue="0.2,0.2,0.4,0.4", units="norm")


def test_the_file_round_trips_and_a_params_layout_table_is_accepted(tmp_path):
    path = tmp_path / "table.toml"
    path.write_text(dump_calibration(MIRRORED, "test"))
    assert load_calibration(path) == MIRRORED
    params = tmp_path / "params.toml"
    params.write_text("[layout.red]\nx1 = 0.7\ny1 = 0.1\nx2 = 0.8\ny2 = 0.2\n")
    assert load_calibration(params).red == Box(0.7, 0.1, 0.8, 0.2)
    bad = tmp_path / "bad.toml"
    bad.write_text("[red]\nx1 = 0.1\nwidth = 3\n")
    with pytest.raises(ConfigError, match="unknown key"):
        load_calibration(bad)


NAMES = ("red", "blue", "green")


@pytest.mark.parametrize("n", [2, 3])
def test_a_file_of_n_boxes_by_option_name_round_trips(tmp_path, n):
    """The paper's red/blue file is the two-option case of a file of boxes by option name."""
    path, names = tmp_path / "table.toml", NAMES[:n]
    if n == 2:  # the paper's file, as `nod vision calibrate` has always written it
        path.write_text(dump_calibration(MIRRORED, "test"))
        want = OptionsLayout.from_table(MIRRORED)
    else:
        boxes = (Box(0.1, 0.1, 0.2, 0.2), Box(0.4, 0.1, 0.5, 0.2), Box(0.7, 0.1, 0.8, 0.2))
        want = OptionsLayout(boxes, CommitLine(0.5, "above"))
        path.write_text(dump_calibration(want, "test", names))
        with pytest.raises(ConfigError, match="unknown key"):  # the paper's reader: two only
            load_calibration(path)
    assert load_boxes(path, names) == want
    assert load_boxes(path, names[::-1]).boxes == want.boxes[::-1]  # by name, not file order
    assert load_commit(path) == want.commit
    with pytest.raises(MissingBoxError, match="no box for option.s. yellow.*--names"):
        load_boxes(path, (*names, "yellow"))
    # what `nod rig`'s preflight reads: the paper's table as it is, or the boxes by name
    assert load_table(path) == (MIRRORED if n == 2 else want)


def test_nod_vision_calibrate_writes_a_table_of_three_boxes_by_colour(tmp_path, capsys):
    layout = OptionsLayout.row(3)
    frame_path, out, preview = tmp_path / "frame.png", tmp_path / "t.toml", tmp_path / "p.png"
    renderer = SceneRenderer(options=painted_boxes(NAMES, layout), noise=2.0)
    cv2.imwrite(str(frame_path), renderer.render((0.5, 0.8)))
    args = ["--frame", str(frame_path), "--names", ",".join(NAMES), "--commit-y", "0.5",
            "--units", "norm", "-o", str(out), "--preview", str(preview)]
    assert main(args) == 0
    assert "green (0." in capsys.readouterr().out
    found = load_boxes(out, NAMES)
    assert found.commit.y == 0.5
    for got, want in zip(found.boxes, layout.boxes, strict=True):
        assert _close(got, want, 2 / 480)
    assert cv2.imread(str(preview)).shape == (480, 640, 3)
    assert main(["--frame", str(frame_path), "--names", "red,blue,green", "--red", "1,2,3,4",
                 "-o", str(out)]) == 2
    assert "drop --red" in capsys.readouterr().err


def test_nod_vision_calibrate_writes_the_file_and_a_preview(tmp_path, capsys):
    frame_path, out, preview = tmp_path / "frame.png", tmp_path / "t.toml", tmp_path / "p.png"
    cv2.imwrite(str(frame_path), SceneRenderer(noise=2.0).render(None))
    args = ["calibrate", "--frame", str(frame_path), "-o", str(out), "--preview", str(preview)]
    assert vision_main(args) == 0
    assert "red (0.72" in capsys.readouterr().out
    layout = load_calibration(out)
    assert _close(layout.red, TableLayout().red, 0.005)
    assert cv2.imread(str(preview)).shape == (480, 640, 3)
    # clicks for one box, colour for the other
    assert main(["--frame", str(frame_path), "--blue", "90,58,180,125", "-o", str(out)]) == 0
    assert load_calibration(out).blue.x2 == pytest.approx(180 / 640, abs=1e-4)


def test_nod_vision_calibrate_fails_in_one_line(tmp_path, capsys):
    assert main(["--frame", str(tmp_path / "none.png"), "-o", str(tmp_path / "t.toml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot read the image" in err
