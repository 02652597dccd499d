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
from services.store.store import (
    DamagedStoreError,
    Store,
    StoreError,
    back_up,
    backup_path,
    check_file,
)

__all__ = [
    "CueRecord",
    "DamagedStoreError",
    "Interruption",
    "QuestionnaireRecord",
    "RigEventRecord",
    "SafetyEvent",
    "Sample",
    "Store",
    "StoreError",
    "TrialRecord",
    "back_up",
    "backup_path",
    "check_file",
    "pack_landmarks",
    "unpack_landmarks",
]
