"""The session store: one SQLite file per study, written by the conductor, read by the tools."""

from services.store.records import (
    CueRecord,
    Interruption,
    QuestionnaireRecord,
    RigEventRecord,
    SafetyEvent,
    Sample,
    TrialRecord,
    pack_landmarks,
    unpack_landmarks,
)
from services.store.store import Store, StoreError

__all__ = [
    "CueRecord",
    "Interruption",
    "QuestionnaireRecord",
    "RigEventRecord",
    "SafetyEvent",
    "Sample",
    "Store",
    "StoreError",
    "TrialRecord",
    "pack_landmarks",
    "unpack_landmarks",
]
