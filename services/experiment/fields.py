"""The fields the conductor sends again and again, typed: a gaze command, a trial's identity."""

from __future__ import annotations

from typing import TypedDict

from services.model.protocol import Mode


class GazeFields(TypedDict, total=False):
    """The gaze command the conductor keeps repeating: fields of `m.GazeMsg`."""

    yaw: float
    pitch: float
    level: str
    gesture: bool
    trial: int


class TrialFields(TypedDict):
    """The trial every event of one cue names: O by name (the key space encodes it)."""

    trial: int
    mode: Mode
    option: str | None
