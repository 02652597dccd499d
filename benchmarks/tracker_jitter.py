"""How much a tracker's hand centre jitters on a still hand: the sim participant's noise, measured.

    python benchmarks/tracker_jitter.py                       # rendered camera, aruco
    python benchmarks/tracker_jitter.py --video still.mp4     # a real recording of a still hand
    python benchmarks/tracker_jitter.py --tracker mediapipe --video still.mp4   # mediapipe extra

Without `--video` the frames come from the synthetic overhead camera (`services.scene`) made
as unkind as a cheap USB camera: Gaussian sensor noise, a slight defocus blur, MJPEG
compression, a mains flicker of the brightness, and a physiological tremor of the hand (8-12 Hz,
sub-millimetre). Each still position is held for `--frames` frames; the jitter is the standard
deviation of the tracked centre about its mean at that position (px, and normalised units that
`ParticipantParams.common_noise` uses), and of its frame-to-frame change (what Algorithm 1's
per-frame movement sees). With `--video` the whole video is one still position.

The rendered numbers are an estimate of a real camera, not a measurement of one: record 10 s
of a still hand on the rig and pass it with `--video` to measure the real thing.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from services.model.geometry import TableLayout  # noqa: E402
from services.scene.render import SceneRenderer  # noqa: E402
from services.vision.trackers import TrackerOptions, make_tracker  # noqa: E402

POSITIONS = ((0.5, 0.85), (0.35, 0.6), (0.65, 0.5), (0.28, 0.3))  # rest, mid-reach, near boxes


def camera_frames(
    renderer: SceneRenderer, x: float, y: float, frames: int, fps: float, rng: np.random.Generator,
    noise: float, blur: float, jpeg: int, flicker: float, tremor_px: float,
):
    """Frames of a still hand at (x, y) through a cheap camera (see the module doc)."""
    for i in range(frames):
        t = i / fps
        # Tremor: a narrow-band 8-12 Hz wobble of the whole hand, sub-pixel at this scale.
        f = rng.uniform(8.0, 12.0)
        dx = tremor_px * math.sin(2 * math.pi * f * t + rng.uniform(0, 0.3)) / renderer.width
        dy = tremor_px * math.cos(2 * math.pi * f * t + rng.uniform(0, 0.3)) / renderer.height
        img = renderer.render((x + dx, y + dy, 0.1)).astype(np.float32)
        if blur > 0:
            img = cv2.GaussianBlur(img, (0, 0), blur)
        # 100 Hz mains flicker sampled at the frame rate: a slow beat of the brightness.
        img *= 1.0 + flicker * math.sin(2 * math.pi * 100.0 * t)
        img += rng.normal(0.0, noise, img.shape).astype(np.float32)
        img = np.clip(img, 0, 255).astype(np.uint8)
        if jpeg:
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, jpeg])
            img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        yield img


def video_frames(path: Path):
    """Every frame of a video file."""
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise SystemExit(f"cannot open {path}")
    while True:
        ok, img = cap.read()
        if not ok:
            break
        yield img
    cap.release()


def measure(tracker, frames) -> tuple[np.ndarray, int, tuple[int, int]]:
    """Tracked centres (px) of every frame where the hand was found; frames seen; (w, h)."""
    centres, seen, size = [], 0, (0, 0)
    for img in frames:
        seen += 1
        h, w = img.shape[:2]
        size = (w, h)
        result = tracker.track(img)
        if result.detected:
            pts = np.asarray(result.landmarks, dtype=float)
            centres.append(pts.mean(axis=0) * (w, h))
    return np.array(centres).reshape(-1, 2), seen, size


def main(argv: list[str] | None = None) -> int:
    """Measure and print the jitter table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracker", default="aruco", help="aruco (default) or mediapipe")
    ap.add_argument("--video", type=Path, help="a recording of a still hand (default: rendered)")
    ap.add_argument("--frames", type=int, default=300, help="frames per still position (300)")
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--noise", type=float, default=3.0, help="sensor noise, grey levels (3)")
    ap.add_argument("--blur", type=float, default=0.8, help="defocus blur sigma, px (0.8)")
    ap.add_argument("--jpeg", type=int, default=80, help="MJPEG quality, 0 = none (80)")
    ap.add_argument("--flicker", type=float, default=0.02, help="brightness flicker (2 %%)")
    ap.add_argument("--tremor", type=float, default=0.3, help="hand tremor amplitude, px (0.3)")
    args = ap.parse_args(argv)
    tracker = make_tracker(args.tracker, TrackerOptions())
    rng = np.random.default_rng(7)
    runs = []
    if args.video:
        runs.append((str(args.video), *measure(tracker, video_frames(args.video))))
    else:
        renderer = SceneRenderer(layout=TableLayout())
        for x, y in POSITIONS:
            frames = camera_frames(
                renderer, x, y, args.frames, args.fps, rng,
                args.noise, args.blur, args.jpeg, args.flicker, args.tremor,
            )
            runs.append((f"({x:.2f}, {y:.2f})", *measure(tracker, frames)))
    print(f"tracker {args.tracker}: jitter of the hand centre on a still hand")
    print(f"{'position':<16}{'found':>8}{'sd x px':>9}{'sd y px':>9}{'sd x':>9}{'sd y':>9}"
          f"{'Δ/frame px':>12}")
    all_sd = []
    for name, centres, seen, (w, h) in runs:
        if len(centres) < 3:
            print(f"{name:<16}{len(centres):>4}/{seen:<3} too few detections")
            continue
        sd = centres.std(axis=0, ddof=1)
        step = np.linalg.norm(np.diff(centres, axis=0), axis=1)
        all_sd.append(sd / (w, h))
        print(f"{name:<16}{len(centres):>4}/{seen:<3}{sd[0]:>9.3f}{sd[1]:>9.3f}"
              f"{sd[0] / w:>9.5f}{sd[1] / h:>9.5f}{np.median(step):>12.3f}")
    if all_sd:
        mean = np.mean(all_sd, axis=0)
        print(f"mean sd (normalised): x {mean[0]:.5f}, y {mean[1]:.5f}; "
              f"ParticipantParams.common_noise is the whole hand's sd per axis")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
