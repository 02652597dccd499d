"""The marker on the back of the hand: its ArUco dictionary and its size against the hand.

Shared by the renderer that draws the marker and the trackers that find it.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

MARKER_PER_RADIUS = 0.6  # marker side / hand radius: the marker covers the back of the hand


def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """A predefined dictionary by its cv2.aruco name, e.g. "DICT_4X4_50"."""
    code = getattr(cv2.aruco, name, None) if name.startswith("DICT_") else None
    if not isinstance(code, int):
        known = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_") and n.isupper())
        raise ValueError(f"unknown ArUco dictionary {name!r}; known: {', '.join(known)}")
    return cv2.aruco.getPredefinedDictionary(code)


def rotation(angle: float) -> np.ndarray:
    """The 2×2 rotation matrix of an in-plane angle (rad)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])
