"""The session store: one SQLite file per study, written by the conductor, read by the tools."""

from services.store.records import QuestionnaireRecord, Sample, TrialRecord
from services.store.store import Store

__all__ = ["QuestionnaireRecord", "Sample", "Store", "TrialRecord"]
