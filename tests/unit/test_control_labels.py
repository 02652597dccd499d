"""SPEC §6: control trials labelled by agreement alone (the default), or by switches; every
analysis says which rule labelled its data, and old stores are read as they were labelled."""

from __future__ import annotations

import csv
import sqlite3
from dataclasses import replace
from pathlib import Path

import pytest

from services.analysis.sessions import control_labels
from services.analysis.study import load_study
from services.experiment.export import export
from services.model.judge import TrialJudge
from services.model.params import NodConfig
from services.model.protocol import ProtocolParams, TrialEnd
from services.store import Store, TrialRecord

CFG = NodConfig()
LAYOUT = CFG.layout
RED, BLUE = LAYOUT.box("red").center, LAYOUT.box("blue").center


def _judged(mode: str, labels: str, human_to: tuple[float, float]) -> tuple[str | None, int]:
    """A trial whose hand reads blue, then switches to red, then presses `human_to`."""
    cfg = replace(CFG, protocol=replace(CFG.protocol, control_labels=labels))
    judge = TrialJudge(cfg, LAYOUT, mode)
    for i in range(12):
        judge.observe(-0.8, (0.5, 0.8), t=float(i))  # blue (beyond the switch dead band)
    for i in range(12, 24):
        judge.observe(0.8, (0.5, 0.8), t=float(i))  # red: one switch
    judge.see_hand([human_to], t=24.0)
    v = judge.verdict(TrialEnd(True, True, 25.0), "red", 10)
    return v.outcome, v.switches


def test_control_trials_by_agreement_consensus_trials_by_switches():
    assert _judged("dissensus", "agreement", RED) == ("C", 1)  # CH by switches
    assert _judged("dissensus", "agreement", BLUE) == ("D", 1)  # DH by switches
    assert _judged("dissensus", "switches", RED) == ("CH", 1)
    assert _judged("consensus", "agreement", RED) == ("CH", 1)  # the rule is for control only
    with pytest.raises(ValueError, match="control_labels"):
        ProtocolParams(control_labels="both")  # type: ignore[arg-type]  # the refused value


def _trial(n: int, outcome: str) -> TrialRecord:
    return TrialRecord(n, "dissensus" if n <= 3 else "consensus", None if n <= 3 else "red",
                       "neutral", 0.0, 0.0, 1, 2, "red", "red", outcome, 0, 0, 10, 2, "pressed")


def _store(path: Path, configs: dict[str, dict]) -> None:
    store = Store(path)
    for i, (pid, config) in enumerate(configs.items()):
        store.begin_session(f"s-{pid}", pid, "sim", i, i, config)
        for n in range(1, 9):
            store.write_trial(f"s-{pid}", _trial(n, "C" if n % 2 else "D"), [])
        store.finish_session(f"s-{pid}", 100 + i)
    store.close()


def test_the_store_says_which_rule_labelled_each_session(tmp_path):
    db = tmp_path / "s.sqlite"
    new = CFG.summary()  # a session stored now: its protocol names the rule
    old = {"protocol": {"trials": new["protocol"]["trials"]}}  # before the rule existed
    _store(db, {"P01": new, "P02": new, "P03": old})
    assert control_labels(None) == "switches"
    doc = load_study(str(db))
    assert doc["control_labels"]["rule"] == "mixed"
    assert doc["control_labels"]["sessions"] == {"agreement": 2, "switches": 1}
    assert {s["participant"]: s["control_labels"] for s in doc["sessions"]} == {
        "P01": "agreement", "P02": "agreement", "P03": "switches"}
    out = tmp_path / "csv"
    with sqlite3.connect(db) as con:
        export(con, out)
    with (out / "sessions.csv").open() as fh:
        rows = {r["participant"]: r["control_labels"] for r in csv.DictReader(fh)}
    assert rows == {"P01": "agreement", "P02": "agreement", "P03": "switches"}
    _store(tmp_path / "one.sqlite", {"P01": new})
    assert "agreement alone" in load_study(str(tmp_path / "one.sqlite"))["control_labels"][
        "description"]
