"""`nod vision` start-up: the layout it publishes and its one-line errors (no Zenoh needed)."""

import sys
import types

import numpy as np
import pytest

from services.model.geometry import Box, CommitLine, OptionsLayout, TableLayout
from services.model.schedule import OptionsSchedule
from services.scene.option_colours import colour_of
from services.scene.render import SceneRenderer, demo_path, write_video
from services.vision.calibration import dump_calibration
from services.vision.overlay import draw_layout
from services.vision.service import (
    OptionsTable,
    PaperTable,
    load_layout,
    main,
    quiet_opencv,
    vision_table,
)


def test_layout_comes_from_calibration_then_params_then_spec(tmp_path):
    cal = tmp_path / "table.toml"
    custom = TableLayout(red=Box(0.1, 0.1, 0.2, 0.2), blue=Box(0.7, 0.1, 0.8, 0.2))
    cal.write_text(dump_calibration(custom))
    params = tmp_path / "params.toml"
    params.write_text("[layout.commit]\ny = 0.6\n")
    assert load_layout(cal, params) == (custom, str(cal))
    layout, origin = load_layout(None, params)
    assert layout.commit.y == 0.6 and "params.toml" in origin
    assert load_layout(None, None) == (TableLayout(), "SPEC defaults")


@pytest.mark.parametrize("n", [2, 3])
def test_the_table_of_n_options_comes_from_a_calibration_file_by_name(tmp_path, n):
    names = ("red", "blue", "green")[:n]
    schedule = None if n == 2 else OptionsSchedule.default(n)
    boxes = (Box(0.1, 0.1, 0.2, 0.2), Box(0.7, 0.1, 0.8, 0.2), Box(0.4, 0.1, 0.5, 0.2))[:n]
    want = OptionsLayout(boxes, CommitLine(0.6))
    cal = tmp_path / "table.toml"
    cal.write_text(dump_calibration(want, names=names))
    table, origin = vision_table(cal, None, schedule)
    assert origin == str(cal) and isinstance(table, PaperTable if n == 2 else OptionsTable)
    assert table.names == names and table.fields is not None
    got = table.layout
    assert (OptionsLayout.from_table(got) if isinstance(got, TableLayout) else got) == want
    table.look(None)  # known: nothing to find, the frame is not even read


def test_a_paper_file_gives_a_table_of_three_its_commit_line_and_colours_the_boxes(tmp_path):
    cal = tmp_path / "table.toml"
    cal.write_text(dump_calibration(TableLayout(commit=CommitLine(0.6))))
    table, origin = vision_table(cal, None, OptionsSchedule.default(3))
    assert isinstance(table, OptionsTable) and table.fields is None and "colours" in origin
    assert table.commit == CommitLine(0.6)


def _fails(capsys, argv, fragment):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("nod vision: ") and err.count("\n") == 1
    assert fragment in err


def test_a_missing_or_unreadable_source_fails_in_one_line(tmp_path, capsys):
    _fails(capsys, ["--source", str(tmp_path / "none.avi")], "video file not found")
    junk = tmp_path / "junk.avi"
    junk.write_bytes(b"\x00" * 4096)
    _fails(capsys, ["--source", str(junk)], "cannot open video file")


def test_bad_options_fail_in_one_line(tmp_path, capsys):
    _fails(capsys, ["--source", "sim", "--frames-key-hz", "99"], "--frames-key-hz")
    _fails(capsys, ["--source", "sim", "--dictionary", "DICT_NONE"], "unknown ArUco dictionary")
    _fails(capsys, ["--source", "sim", "--calibration", str(tmp_path / "x.toml")], "not found")


def test_the_mediapipe_tracker_without_its_extra_fails_in_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "mediapipe", None)  # `import mediapipe` fails, as without it
    video = tmp_path / "v.avi"
    write_video(video, SceneRenderer(width=160, height=120), demo_path(), fps=2.0)
    _fails(
        capsys,
        ["--source", str(video), "--tracker", "mediapipe"],
        "scripts/setup-env --mediapipe",
    )


class _OpenCV4:
    """The log-level API of OpenCV 4.x: `cv2.utils` without `logging`, `cv2.setLogLevel`."""

    def __init__(self) -> None:
        self.utils = types.SimpleNamespace()  # 4.11 has cv2.utils, but no cv2.utils.logging
        self.levels: list[int] = []

    def setLogLevel(self, level: int) -> None:
        self.levels.append(level)


def test_opencv_is_quietened_on_opencv_4_and_5():
    """OpenCV 4 has no cv2.utils.logging, only cv2.setLogLevel: start-up must not depend on it."""
    old = _OpenCV4()
    quiet_opencv(old)
    assert old.levels == [2]  # cv::utils::logging::LOG_LEVEL_ERROR
    import cv2  # the installed one (5.x with constraints.txt)

    api = getattr(cv2.utils, "logging", cv2)
    before = api.getLogLevel()
    try:
        quiet_opencv(cv2)
        assert api.getLogLevel() == 2
    finally:
        api.setLogLevel(before)


@pytest.mark.parametrize("n", [2, 3])
def test_the_monitor_frame_outlines_every_box_in_its_options_colour(n):
    """The paper's table in its red and blue; N boxes in their options' paint; none unfound."""
    names = ("red", "blue", "green")[:n]
    table = TableLayout() if n == 2 else OptionsLayout.row(n)
    img = draw_layout(np.zeros((480, 640, 3), np.uint8), table, names)
    boxes = (table.red, table.blue) if isinstance(table, TableLayout) else table.boxes
    for name, box in zip(names, boxes, strict=True):
        x, y = round(box.x1 * 640 - 0.5), round(box.center[1] * 480)
        bgr = {"red": (0, 0, 255), "blue": (255, 64, 0)}[name] if n == 2 else colour_of(name)[0]
        assert tuple(img[y, x]) == bgr, name
    assert not draw_layout(np.zeros((48, 64, 3), np.uint8), None).any()
