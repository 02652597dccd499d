"""What the session store keeps, as plain dataclasses (no database needed to build one)."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class TrialRecord:
    """One finished trial as stored."""

    trial: int
    mode: str
    option: str | None
    gaze_level: str
    yaw: float
    pitch: float
    t_go_ns: int | None
    t_end_ns: int | None
    human: str | None
    robot: str | None
    outcome: str | None
    switches: int
    violations: int
    clicks: int | None
    score: int
    end_reason: str
    interrupted: bool = False  # broken by a safe stop or e-stop and not repeated: never scored
    attempts: int = 1  # starts of this trial, the interrupted ones included


@dataclass(frozen=True, slots=True)
class Sample:
    """One decimated sample of a trial's streams."""

    t_ns: int
    detected: bool
    hand_x: float | None
    hand_y: float | None
    z_h: float | None
    z_r: float | None
    b_r: float | None
    ee_x: float | None
    ee_y: float | None
    theta: float | None = None  # eq 7's θ (rad) when this pose set ẑ_h
    distance: float | None = None  # eq 7's d when this pose set ẑ_h
    # The tracker's landmarks of this pose (`pack_landmarks`: float32 x, y pairs), so a session
    # can be re-analysed — another observer, another hand centre — without its recording.
    landmarks: bytes | None = None


def pack_landmarks(points: Sequence[tuple[float, float]]) -> bytes:
    """Landmarks (x, y) as 8 bytes each (float32 x then y), in order."""
    return struct.pack(f"<{2 * len(points)}f", *(c for p in points for c in p))


def unpack_landmarks(blob: bytes | None) -> tuple[tuple[float, float], ...]:
    """The landmarks `pack_landmarks` stored; () for None. ValueError for a torn blob."""
    if not blob:
        return ()
    if len(blob) % 8:
        raise ValueError(f"landmark blob of {len(blob)} bytes is not a whole number of points")
    values = struct.unpack(f"<{len(blob) // 4}f", blob)
    return tuple(zip(values[0::2], values[1::2], strict=True))


@dataclass(frozen=True, slots=True)
class QuestionnaireRecord:
    """One participant's answers to Q1-Q5 of Sec 8 (validated by services.experiment.questionnaire).

    Q1, Q2, Q4, Q5 are Likert ratings 1-10; Q3 is 'Yes', 'No' or 'Maybe'.
    """

    participant: str
    q1: int
    q2: int
    q3: str
    q4: int
    q5: int


@dataclass(frozen=True, slots=True)
class SafetyEvent:
    """A change of the rig's safety state seen by the conductor during a session."""

    trial: int  # the trial under way or last started (0 before the first)
    attempt: int  # which start of that trial
    t_ns: int
    device: str  # "actuation", "eyes", "estop" (the operator's command), "rig" (a hostile input)
    event: str  # "safe_stop", "clear", "estop", "release"
    reason: str


@dataclass(frozen=True, slots=True)
class RigEventRecord:
    """A launcher's event (a service started, died, restarted, given up) seen during a session."""

    trial: int
    attempt: int
    t_ns: int
    host: str
    service: str
    kind: str  # "started", "exited", "restarting", "gave_up", "stopped"
    code: int | None  # exit code; negative: the signal that killed it
    text: str


@dataclass(frozen=True, slots=True)
class CueRecord:
    """A countdown word or go as the speaker played it (`speaker/played`), rig-clock ns."""

    trial: int
    attempt: int  # which start of that trial
    cue: str  # the word: "1", "2", "3", "go"
    planned_ns: int  # the cue's `experiment/trial` event
    played_ns: int  # when the sound started


@dataclass(frozen=True, slots=True)
class Interruption:
    """One start of a trial that a safe stop or an e-stop broke."""

    trial: int
    attempt: int
    t_start_ns: int  # the trial's setup
    t_ns: int  # when it was broken
    reason: str
