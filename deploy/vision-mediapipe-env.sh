#!/usr/bin/env bash
# Build the camera box's own Python environment for `nod vision --tracker mediapipe`.
#
# Why a separate environment: mediapipe 0.10.21 is the last release that ships its hand models
# inside the wheel (later ones download them at run time, which lab networks cannot rely on), and
# it needs numpy < 2 and opencv-contrib-python — while the rest of nod-hri runs on numpy 2 and
# opencv-python-headless. So this venv pins mediapipe's side, installs the few runtime
# dependencies the vision service needs at versions that work with numpy 1.26, and installs
# nod-hri itself with --no-deps (the main .venv stays as it is).
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
"${pip[@]}" install \
    "mediapipe==0.10.21" \
    "numpy>=1.26,<2" \
    "opencv-contrib-python>=4.9,<4.12" \
    "eclipse-zenoh>=1.4,<2" \
    "msgpack>=1.0" \
    "pyserial>=3.5"
# mediapipe pulls opencv-contrib-python; make sure no second cv2 (headless) shadows it.
"${pip[@]}" uninstall -q -y opencv-python-headless opencv-python 2>/dev/null || true
if [ "${NOD_EDITABLE:-0}" = "1" ]; then
    "${pip[@]}" install -q --no-deps -e "$root"
else
    "${pip[@]}" install -q --no-deps "$root"
fi

# Prove it: numpy < 2, the hand model loads from the wheel (no download) and runs on a frame.
"$venv/bin/python" - <<'PYCHECK'
import cv2
import numpy as np
import mediapipe

from services.vision.trackers import TrackerOptions
from services.vision.trackers.mediapipe import MediapipeTracker

assert np.__version__.startswith("1."), f"numpy {np.__version__} in the camera-box env"
with MediapipeTracker(TrackerOptions()) as tracker:
    result = tracker.track(np.zeros((480, 640, 3), np.uint8))
assert not result.detected
print(
    f"camera-box environment ready: mediapipe {mediapipe.__version__}, numpy {np.__version__}, "
    f"opencv {cv2.__version__}"
)
PYCHECK
echo "run: $venv/bin/nod vision --source 0 --tracker mediapipe --calibration /etc/nod/table.toml"
