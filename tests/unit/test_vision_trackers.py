"""Hand trackers on rendered frames and on video files: the centre path, misses, options."""

import math
import sys

import numpy as np
import pytest

from services.model.geometry import HAND_TEMPLATE, Box, TableLayout
from services.scene.render import HandPath, RenderedSource, SceneRenderer, demo_path, write_video
from services.vision.capture import Capture, Source
from services.vision.trackers import (
    NOT_DETECTED,
    TrackerOptions,
    TrackerUnavailableError,
    TrackResult,
    make_tracker,
)
from services.vision.trackers.aruco import ArucoTracker
from services.vision.trackers.sim import SimTracker

TOL = 0.01  # normalised: the bound on the centre error


def _share_within(results, truth, tol=TOL):
    ok = 0
    for res, hand in zip(results, truth, strict=True):
        if hand is not None and res.detected and math.dist(res.center, hand[:2]) <= tol:
            ok += 1
    return ok / sum(h is not None for h in truth)


def test_track_result_centre_is_the_mean_of_landmarks():
    r = TrackResult(True, ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)))
    assert r.center == (0.5, 0.5)
    assert NOT_DETECTED.center is None
    with pytest.raises(ValueError, match="needs landmarks"):
        TrackResult(True, ())
    with pytest.raises(ValueError):
        TrackResult(False, ((0.5, 0.5),))


def test_aruco_recovers_the_centre_path_on_rendered_frames():
    renderer = SceneRenderer(noise=4.0)
    truth = demo_path().sample(90, 12.0)  # the whole 7 s path, 12 fps
    tracker = ArucoTracker()
    results = [tracker.track(renderer.render(h)) for h in truth]
    assert _share_within(results, truth) >= 0.95
    for res in results:
        assert res.detected and len(res.landmarks) == 4


def test_aruco_recovers_the_centre_path_from_an_mjpg_file(tmp_path):
    video = tmp_path / "path.avi"
    truth = write_video(video, SceneRenderer(noise=2.0), demo_path(), fps=15.0)
    cap = Capture(Source("file", str(video)))
    cap.open()
    cap.start()
    tracker = ArucoTracker()
    results = []
    try:
        while (frame := cap.next(timeout=2.0)) is not None:
            assert frame.seq == len(results)  # a file is read losslessly
            results.append(tracker.track(frame.image))
    finally:
        cap.close()
    assert len(results) == len(truth)
    assert _share_within(results, truth) >= 0.95


def test_rotated_and_mirrored_scenes_are_tracked():
    mirrored = TableLayout(red=Box(0.14, 0.12, 0.28, 0.26), blue=Box(0.72, 0.12, 0.86, 0.26))
    renderer = SceneRenderer(layout=mirrored, width=800, height=600, noise=3.0)
    tracker = ArucoTracker()
    for k, angle in enumerate(np.linspace(-0.6, 0.6, 9)):
        hand = (0.2 + 0.07 * k, 0.3 + 0.05 * k, float(angle))
        res = tracker.track(renderer.render(hand))
        assert res.detected
        assert math.dist(res.center, hand[:2]) < 0.002


def test_a_missing_marker_gives_detected_false():
    renderer = SceneRenderer()
    hidden = HandPath(((0.0, 0.5, 0.8), (0.5, None, None), (1.0, 0.5, 0.8)))
    truth = hidden.sample(20, 20.0)
    assert any(h is None for h in truth)
    for tracker in (ArucoTracker(), SimTracker()):
        for hand in truth:
            res = tracker.track(renderer.render(hand))
            assert res.detected == (hand is not None)
            if not res.detected:
                assert res == NOT_DETECTED and res.landmarks == ()


def test_marker_id_selects_the_hand_marker():
    frame = SceneRenderer(marker_id=7).render((0.5, 0.6))
    assert ArucoTracker(TrackerOptions(marker_id=7)).track(frame).detected
    assert not ArucoTracker(TrackerOptions(marker_id=3)).track(frame).detected
    other_dict = ArucoTracker(TrackerOptions(dictionary="DICT_6X6_50"))
    assert not other_dict.track(frame).detected


def test_sim_tracker_poses_21_landmarks_whose_mean_is_the_marker_centre():
    renderer = SceneRenderer(noise=2.0)
    hand = (0.62, 0.55, 0.3)
    res = SimTracker().track(renderer.render(hand))
    assert res.detected and len(res.landmarks) == 21
    assert math.dist(res.center, hand[:2]) < 0.002
    expected = renderer.hand_landmarks(*hand)
    assert np.abs(np.array(res.landmarks) - expected).max() < 0.01
    assert np.allclose(HAND_TEMPLATE.mean(axis=0), 0.0)


def test_rendered_source_serves_the_path_like_a_capture():
    renderer = SceneRenderer(width=320, height=240)
    src = RenderedSource(renderer, demo_path(), fps=10.0)
    n = 0
    while True:
        ok, img = src.read()
        if not ok:
            break
        assert img.shape == (240, 320, 3)
        n += 1
    assert n == len(src.truth) == 71


def test_unknown_names_fail_with_the_known_ones():
    with pytest.raises(ValueError, match="choose one of"):
        make_tracker("magic")
    with pytest.raises(ValueError, match="DICT_4X4_50"):
        make_tracker("aruco", TrackerOptions(dictionary="DICT_NOPE"))


def test_mediapipe_absent_is_one_clear_line_naming_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "mediapipe", None)  # `import mediapipe` fails, as without it
    with pytest.raises(TrackerUnavailableError) as err:
        make_tracker("mediapipe")
    text = str(err.value)
    assert "\n" not in text
    assert "scripts/setup-env --mediapipe" in text and "0.10.21" in text


def test_mediapipe_loads_its_model_and_runs_on_frames():
    pytest.importorskip(
        "mediapipe",
        reason="the mediapipe extra is not installed (scripts/setup-env --mediapipe)",
    )
    renderer = SceneRenderer()
    with make_tracker("mediapipe", TrackerOptions(model_complexity=0)) as tracker:
        for hand in ((0.5, 0.6), None):
            res = tracker.track(renderer.render(hand))
            if res.detected:  # a drawn hand may or may not pass for a real one
                assert len(res.landmarks) == 21
            else:
                assert res.landmarks == ()
