"""One study from two rigs' stores: analysed and exported as one, never merging a participant.

The split is checked against the union: the same sessions in one store give the same study.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from functools import cache
from pathlib import Path

import pytest

from services.analysis.study import load_study
from services.model.closed_loop import OfflineTrial, run_offline_session
from services.model.params import NodConfig
from services.sim.cohort import offline_record
from services.store import QuestionnaireRecord, Sample, Store

ROOT = Path(__file__).resolve().parents[2]
RIGS = {"rig1": ("P01", "P02", "P03"), "rig2": ("P04", "P05", "P06")}


@cache
def _session(seed: int) -> list[OfflineTrial]:
    return run_offline_session(NodConfig(), seed, cohort=True)


def _write(store: Store, pid: str, rig: str, seed: int, started: int, answers: bool = True) -> None:
    cfg = NodConfig()
    sid = f"s-{pid}-{rig}"
    store.begin_session(sid, pid, rig, seed, started, cfg.summary())
    for t in _session(seed):
        rec = offline_record(t, cfg.protocol.trials[t.trial - 1], started + t.trial * 10**10)
        store.write_trial(sid, rec, [Sample(0, True, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)])
    store.finish_session(sid, started + 10**12, "complete")
    if answers:
        store.write_questionnaires(
            [QuestionnaireRecord(pid, 7, 6, "Yes", 8, seed % 10 + 1)], 0, "test")


@pytest.fixture(scope="module")
def stores(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """rig1.sqlite and rig2.sqlite, three participants each, and all.sqlite with all six."""
    folder = tmp_path_factory.mktemp("rigs")
    paths = {name: folder / f"{name}.sqlite" for name in ("rig1", "rig2", "all")}
    opened = {name: Store(p) for name, p in paths.items()}
    for seed, (rig, pid) in enumerate((r, p) for r, ps in RIGS.items() for p in ps):
        for name in (rig, "all"):
            _write(opened[name], pid, rig, seed, 10**15 * (seed + 1))
    for s in opened.values():
        s.close()
    return paths


def test_two_stores_are_one_study_and_each_session_keeps_its_rig(stores) -> None:
    split = load_study([str(stores["rig1"]), str(stores["rig2"])])
    union = load_study(str(stores["all"]))
    assert split["participants"] == 6 and split["rigs"] == {"rig1": 3, "rig2": 3}
    assert {s["participant"]: s["rig"] for s in split["sessions"]} == {
        p: rig for rig, ps in RIGS.items() for p in ps}
    assert split["stores"] == [str(stores["rig1"]), str(stores["rig2"])]
    for key in ("frequencies", "grid", "contingency", "stuart_maxwell", "questionnaire"):
        assert split[key] == union[key], key  # the same numbers as one store of all six


def _nod(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "services.cli", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def test_the_commands_take_several_stores(stores, tmp_path: Path) -> None:
    both = ["--db", str(stores["rig1"]), "--db", str(stores["rig2"])]
    res = _nod("analyze", "study", *both, "--json")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["participants"] == 6
    text = _nod("analyze", "study", *both)
    assert "participants 3 on rig1, 3 on rig2" in text.stdout, text.stdout
    out = tmp_path / "csv"
    res = _nod("export", *both, "--out", str(out))
    assert res.returncode == 0, res.stderr
    union = tmp_path / "union"
    assert _nod("export", "--db", str(stores["all"]), "--out", str(union)).returncode == 0

    def rows(folder: Path, name: str) -> list[dict[str, str]]:
        with (folder / f"{name}.csv").open(newline="") as fh:
            return list(csv.DictReader(fh))

    sessions = rows(out, "sessions")
    assert {r["participant"]: r["rig"] for r in sessions} == {
        p: rig for rig, ps in RIGS.items() for p in ps}
    for name in ("sessions", "trials", "samples", "questionnaires", "cues"):
        assert rows(out, name) == rows(union, name), name  # the union's rows, in its order


def test_a_participant_in_two_stores_or_on_two_rigs_is_one_line(stores, tmp_path: Path) -> None:
    again = tmp_path / "again.sqlite"
    store = Store(again)
    _write(store, "P02", "rig3", 1, 1)  # P02 again, on another rig's store
    store.close()
    for command in (["analyze", "study"], ["export", "--out", str(tmp_path / "x")]):
        res = _nod(*command, "--db", str(stores["rig1"]), "--db", str(again))
        assert res.returncode == 2
        assert res.stderr.count("\n") == 1, res.stderr
        assert "participant P02 is in two stores" in res.stderr
        assert str(stores["rig1"]) in res.stderr and str(again) in res.stderr
    assert not (tmp_path / "x").exists()  # nothing written
    two_rigs = tmp_path / "two-rigs.sqlite"
    store = Store(two_rigs)
    _write(store, "P07", "rig1", 0, 1)
    _write(store, "P07", "rig2", 1, 2, answers=False)
    store.close()
    with pytest.raises(ValueError, match="P07 has sessions on rigs rig1 and rig2"):
        load_study(str(two_rigs))
    res = _nod("analyze", "study", "--db", str(stores["rig1"]), "--db", str(stores["rig1"]))
    assert res.returncode == 2 and "given twice" in res.stderr
