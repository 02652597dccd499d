"""Tracker frames per second on 640×480, against the bare decode rate of the same file.

One run writes a 640×480 MJPG file of the rendered table with a moving marker (the demo path),
then measures, on this machine and in this run:

- **Baseline**: bare decode, `cv2.VideoCapture(file).read()` in a loop.
- **In-process**: decode + `tracker.track(frame)` for every available tracker (aruco, sim, and
  mediapipe where the `mediapipe` extra is installed), with the share of frames whose centre is
  within 0.01 of the rendered truth.
- **End to end**: the real service, `python -m services.cli vision --source FILE --tracker T`,
  against a router on a free loopback port; a subscriber counts the hand poses and times the
  first to the last arrival (capture thread, tracking, encoding, publishing, delivery).

Prints every rate and its ratio to the decode rate. Goal: end to end ≥ 60 fps
(twice a 30 fps camera) for each tracker except mediapipe, which is reported; exits 1 if missed.

    .venv/bin/python benchmarks/vision_fps.py [--frames 600] [--repeat 3]
    (mediapipe is included once `scripts/setup-env --mediapipe` has installed the extra)
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2

from services.core import messages as m
from services.core.keys import Keys
from services.core.session import make_config, open_session
from services.scene.render import SceneRenderer, demo_path
from services.vision.trackers import TrackerOptions, make_tracker

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)  # the tests' helpers
from tests.processes import free_port  # noqa: E402

GOAL_FPS = 60.0


def decode_fps(video: Path) -> float:
    cap = cv2.VideoCapture(str(video))
    n, t0 = 0, time.perf_counter()
    while cap.read()[0]:
        n += 1
    dt = time.perf_counter() - t0
    cap.release()
    return n / dt


def track_fps(video: Path, name: str, truth: list) -> tuple[float, float, float]:
    tracker = make_tracker(name, TrackerOptions(model_complexity=0))
    cap = cv2.VideoCapture(str(video))
    results = []
    t0 = time.perf_counter()
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        results.append(tracker.track(frame))
    dt = time.perf_counter() - t0
    cap.release()
    tracker.close()
    good = sum(
        1
        for r, h in zip(results, truth, strict=False)
        if h is not None and r.detected and math.dist(r.center, h[:2]) <= 0.01
    )
    seen = sum(r.detected for r in results)
    return len(results) / dt, good / len(results), seen / len(results)


def service_fps(video: Path, name: str, n_frames: int) -> float:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session(make_config(mode="router", listen=[endpoint]))
    client = open_session(make_config(mode="client", connect=[endpoint]))
    arrivals: list[float] = []
    done = threading.Event()

    def on_pose(sample) -> None:
        m.decode(m.HandPose, sample.payload.to_bytes())
        arrivals.append(time.perf_counter())
        if len(arrivals) >= n_frames:
            done.set()

    sub = client.declare_subscriber(Keys("bench").topic("vision/hand"), on_pose)
    cmd = [sys.executable, "-m", "services.cli", "vision", "--connect", endpoint, "--rig", "bench"]
    cmd += ["--source", str(video), "--tracker", name, "--wait-for-subscriber", "10"]
    if name == "mediapipe":
        cmd += ["--model-complexity", "0"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        proc.wait(120)
        done.wait(3)  # the last poses may still be in flight
    finally:
        if proc.poll() is None:
            proc.kill()
        sub.undeclare()
        client.close()
        router.close()
    if proc.returncode != 0 or len(arrivals) < 2:
        err = proc.stderr.read().decode() if proc.stderr else ""
        raise RuntimeError(f"nod vision --tracker {name} failed ({proc.returncode}): {err[-500:]}")
    if len(arrivals) < n_frames:
        print(f"  ({name}: {n_frames - len(arrivals)} of {n_frames} poses lost)")
    return (len(arrivals) - 1) / (arrivals[-1] - arrivals[0])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=600, help="frames in the test file")
    p.add_argument("--repeat", type=int, default=3, help="best of this many runs of each")
    args = p.parse_args()
    trackers = ["aruco", "sim"]
    if importlib.util.find_spec("mediapipe") is not None:
        trackers.append("mediapipe")
    with tempfile.TemporaryDirectory() as tmp:
        video = Path(tmp) / "bench.avi"
        fps = 30.0
        path = demo_path()
        reps = max(1, math.ceil(args.frames / (path.duration * fps)))
        truth = (path.sample(int(path.duration * fps), fps) * reps)[: args.frames]  # repeated
        _write(video, SceneRenderer(noise=2.0), truth, fps)
        base = max(decode_fps(video) for _ in range(args.repeat))
        print(f"640x480 MJPG, {len(truth)} frames, {os.cpu_count()} CPUs, best of {args.repeat}")
        print(f"{'decode only (baseline)':<30}{base:8.1f} fps")
        failed = False
        for name in trackers:
            runs = [track_fps(video, name, truth) for _ in range(args.repeat)]
            rate, acc, seen = max(runs)
            e2e = max(service_fps(video, name, len(truth)) for _ in range(args.repeat))
            print(
                f"{name + ' in-process':<30}{rate:8.1f} fps  ({rate / base:.2f} x decode)"
                f"  hand seen {100 * seen:.0f} %, centre within 0.01: {100 * acc:.1f} %"
            )
            print(
                f"{name + ' end to end (service)':<30}{e2e:8.1f} fps  ({e2e / base:.2f} x decode)"
            )
            if name != "mediapipe" and e2e < GOAL_FPS:
                failed = True
        print(f"goal: end to end >= {GOAL_FPS:.0f} fps -> {'MISSED' if failed else 'met'}")
        return 1 if failed else 0


def _write(video: Path, renderer: SceneRenderer, truth: list, fps: float) -> None:
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), fps, (640, 480))
    for hand in truth:
        writer.write(renderer.render(hand))
    writer.release()


if __name__ == "__main__":
    sys.exit(main())
