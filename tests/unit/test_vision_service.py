"""`nod vision` start-up: the layout it publishes and its one-line errors (no Zenoh needed)."""

import sys
import types

from services.model.geometry import Box, TableLayout
from services.scene.render import SceneRenderer, demo_path, write_video
from services.vision.calibration import dump_calibration
from services.vision.service import load_layout, main, quiet_opencv


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
