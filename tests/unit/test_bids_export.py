"""`nod export --bids`: a simulated study as a BIDS dataset the official validator accepts.

The study: two participants of the offline closed loop (`nod cohort`'s simulation, no rig, no
cues stored) in one store, and the golden's store (a distributed `nod run --sim` session with
the speaker's played cues and safety events) as a second store of the same study. The validator
is the official one (`bids-validator-deno`, a test dependency), run on every row.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from services.cohort.person import load_cohort_params
from services.core.provenance import Provenance
from services.experiment.bids import export_bids, subject_labels
from services.experiment.bids_sidecars import CHANNELS
from services.experiment.export import main
from services.model.policy import PolicySettings
from services.sim.cohort import Job, simulate, store_session
from services.store import Store
from services.store.estimates import ParamRow, TrialEstimate, write_estimate
from services.store.policies import write_policy
from services.store.provenance import write_provenance
from services.store.study_stores import open_stores, union_of
from services.store.withdrawals import WithdrawnFilter

ROOT = Path(__file__).resolve().parents[2]
GOLDEN_STORE = ROOT / "tests" / "golden" / "store-2026-12.sqlite"
VALIDATOR = Path(sys.executable).parent / "bids-validator-deno"
# One run's provenance, stored with the first offline session (as a conductor would store it).
RUN = Provenance(
    version="1.2.3", sources_sha256="ab" * 32, params_hash="0123456789ab", params_sha256="cd" * 32,
    params_file="/home/lab/params.toml", study_file="/home/lab/study.toml", study_sha256="ef" * 32,
    study_name="pilot", consent_version="v2", allocation_seed=7, preregistration="osf.io/ab12c",
    hosts={"decision": ("lab-pc1",)}, recording_file="/home/lab/s.mcap",
    recording_sha256="12" * 32,
)


SETTINGS = {t: PolicySettings(6.0 if t > 4 else 4.54, "extreme" if t > 3 else "neutral", 2.24)
            for t in range(1, 9)}


def _cohort(path: Path, seeds: tuple[int, ...], prefix: str = "cohort", index0: int = 0) -> None:
    """Offline sessions of `nod cohort`'s person, stored as `nod cohort` stores them."""
    cfg = load_cohort_params(None)
    with Store(path) as store:
        for i, seed in enumerate(seeds):
            job = Job(index0 + i, seed, cfg, True)
            store_session(store, job, simulate(job), prefix)


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """The study's two stores: two offline participants, and the golden's rig session."""
    where = tmp_path_factory.mktemp("study")
    _cohort(where / "cohort.sqlite", (1, 2))
    with Store(where / "cohort.sqlite") as store:
        (first,) = store.db.execute(
            "SELECT session FROM sessions ORDER BY started_ns, session LIMIT 1").fetchone()
        write_provenance(store, first, 1, RUN)
        # The first session ran a robot policy and a live estimator (as a rig with `nod
        # experiment --policy` and `nod estimate` stores them).
        write_policy(store, first, "mine", "ab" * 32, "firm", SETTINGS)
        for trial in range(1, 9):
            write_estimate(store, first, TrialEstimate(trial, trial, 0.02, (
                ParamRow("speed", 1.0 + trial / 10, 0.5, 2.5, None),
                ParamRow("contrarian", 1.0, 0.0, 1.0, 0.75))))
    shutil.copy(GOLDEN_STORE, where / "rig.sqlite")
    return [where / "cohort.sqlite", where / "rig.sqlite"]


@pytest.fixture(scope="module")
def dataset(study: list[Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The study exported by the command line."""
    out = tmp_path_factory.mktemp("bids") / "ds"
    args = [a for db in study for a in ("--db", str(db))]
    assert main([*args, "--bids", str(out)]) == 0
    return out


def _tsv(path: Path) -> list[dict[str, str]]:
    with path.open(encoding="utf-8", newline="") as fh:
        return list(csv.DictReader(fh, delimiter="\t"))


def _validate(root: Path) -> list[dict]:
    """The official validator's issues on every row of every file (no network needed)."""
    if not VALIDATOR.exists():
        pytest.fail(f"{VALIDATOR} is missing: scripts/setup-env installs the test extra")
    run = subprocess.run(
        [str(VALIDATOR), str(root), "--format", "json", "--max-rows", "-1"],
        capture_output=True, text=True, timeout=120, check=False,
        env={**os.environ, "DENO_NO_UPDATE_CHECK": "1"},  # Deno's release check: no network
    )
    assert run.stdout, run.stderr
    return json.loads(run.stdout)["issues"]["issues"]


def test_the_official_validator_finds_no_error(dataset: Path) -> None:
    issues = _validate(dataset)
    errors = [(i["code"], i.get("location"), i.get("issueMessage")) for i in issues
              if i["severity"] == "error"]
    assert errors == []
    # Every warning left is one docs/data.md explains: facts a lab adds (authors, licence,
    # institution) or vocabularies this task has no entry in.
    explained = {"HEDVersion", "License", "SourceDatasets", "Authors", "CogAtlasID", "CogPOID",
                 "InstitutionAddress", "InstitutionName", "InstitutionalDepartmentName",
                 "TOO_FEW_AUTHORS"}
    assert {i.get("subCode") or i["code"] for i in issues} <= explained


def test_events_have_the_go_of_every_trial(dataset: Path, study: list[Path]) -> None:
    with open_stores(study) as stores, union_of(stores) as db:
        stored = db.execute(
            "SELECT s.participant, t.trial, t.t_go_ns - s.started_ns FROM trials t JOIN sessions s "
            "ON s.session = t.session WHERE t.t_go_ns IS NOT NULL").fetchall()
    assert len(stored) == 8 + 8 + 3
    for participant, trial, go_ns in stored:
        events = _tsv(dataset / f"sub-{participant}" / "beh" /
                      f"sub-{participant}_task-consensus_events.tsv")
        go = [e for e in events if e["trial_type"] == "go" and e["trial"] == str(trial)]
        assert len(go) == 1, (participant, trial)
        assert float(go[0]["planned_onset"]) == pytest.approx(go_ns / 1e9, abs=1e-6)
        # played (the speaker's time) never before it was asked for, nor long after
        assert -1e-6 <= float(go[0]["onset"]) - go_ns / 1e9 < 0.1
        onsets = [float(e["onset"]) for e in events]
        assert onsets == sorted(onsets)


def test_cues_as_played_where_stored_else_scheduled(dataset: Path) -> None:
    rig = _tsv(dataset / "sub-P01" / "beh" / "sub-P01_task-consensus_events.tsv")
    words = [(e["trial"], e["value"], e["source"]) for e in rig
             if e["trial_type"] in ("countdown", "go")]
    assert words == [(str(t), w, "played") for t in (1, 2, 3) for w in ("1", "2", "3", "go")]
    assert {e["trial_type"] for e in rig} >= {"safe_stop", "safe_clear", "gaze", "human_press",
                                               "robot_press", "trial_end"}
    offline = _tsv(dataset / "sub-P001" / "beh" / "sub-P001_task-consensus_events.tsv")
    first = [e for e in offline if e["trial"] == "1" and e["trial_type"] in ("gaze", "countdown")]
    assert [(e["trial_type"], e["source"]) for e in first] == [
        ("gaze", "schedule"), *[("countdown", "schedule")] * 3]
    go = next(e for e in offline if e["trial"] == "1" and e["trial_type"] == "go")
    # the schedule: gaze 1 s before the first word, words 0.75 s apart, the last one the go
    assert float(go["onset"]) - float(first[0]["onset"]) == pytest.approx(1.0 + 3 * 0.75)


def test_every_column_and_channel_is_described(dataset: Path) -> None:
    for sub in ("P001", "P002", "P01"):
        beh = dataset / f"sub-{sub}" / "beh"
        for suffix in ("beh", "events"):
            rows = _tsv(beh / f"sub-{sub}_task-consensus_{suffix}.tsv")
            sidecar = json.loads((beh / f"sub-{sub}_task-consensus_{suffix}.json").read_text())
            assert set(rows[0]) <= set(sidecar), suffix
        motion = next((dataset / f"sub-{sub}" / "motion").glob("*_motion.tsv"))
        channels = _tsv(Path(str(motion).replace("_motion.tsv", "_channels.tsv")))
        assert [c["name"] for c in channels] == [c.name for c in CHANNELS]
        lines = motion.read_text().splitlines()
        assert all(len(line.split("\t")) == len(channels) for line in lines)
        meta = json.loads(motion.with_suffix(".json").read_text())
        assert meta["SamplingFrequency"] == pytest.approx(30.0, abs=0.5)  # the camera's rate
        assert "simulated" in motion.name and "SIMULATED" in meta["Notes"]
    beh = _tsv(dataset / "sub-P001" / "beh" / "sub-P001_task-consensus_beh.tsv")
    assert [r["trial"] for r in beh] == [str(n) for n in range(1, 9)]
    people = _tsv(dataset / "participants.tsv")
    assert [(p["participant_id"], p["simulated"]) for p in people] == [
        ("sub-P001", "true"), ("sub-P002", "true"), ("sub-P01", "true")]
    description = json.loads((dataset / "dataset_description.json").read_text())
    assert description["GeneratedBy"][0]["Name"] == "nod-hri"
    assert "every session SIMULATED" in description["GeneratedBy"][0]["Description"]


def test_several_sessions_of_one_person_are_ses_levels(tmp_path: Path) -> None:
    db = tmp_path / "again.sqlite"
    _cohort(db, (1,), "first")
    _cohort(db, (2,), "again")  # index 0 again: participant P001's second session
    out = tmp_path / "ds"
    with open_stores([db]) as stores, union_of(stores) as conn:
        written = export_bids(conn, out, WithdrawnFilter({}))
    assert (written.participants, written.sessions) == (1, 2)
    sessions = _tsv(out / "sub-P001" / "sub-P001_sessions.tsv")
    assert [s["session_id"] for s in sessions] == ["ses-1", "ses-2"]
    assert (out / "sub-P001" / "ses-2" / "beh" / "sub-P001_ses-2_task-consensus_beh.tsv").is_file()
    assert [i for i in _validate(out) if i["severity"] == "error"] == []


def test_a_withdrawn_participant_is_not_exported(study: list[Path], tmp_path: Path) -> None:
    with open_stores(study) as stores, union_of(stores) as db:
        written = export_bids(db, tmp_path, WithdrawnFilter({"P002": False}))
    assert written.participants == 2
    assert not (tmp_path / "sub-P002").exists()
    assert "sub-P002" not in (tmp_path / "participants.tsv").read_text()


def test_ids_that_become_one_label_are_refused() -> None:
    assert subject_labels(["P-01", "P_02"]) == {"P-01": "P01", "P_02": "P02"}
    with pytest.raises(ValueError, match="both sub-P01"):
        subject_labels(["P-01", "P01"])


def test_the_command_says_where_in_one_line(study: list[Path], capsys) -> None:
    assert main(["--db", str(study[0])]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("nod export: error: say where") and "\n" not in err


def test_a_session_with_no_samples_has_no_motion(tmp_path: Path) -> None:
    db = tmp_path / "bare.sqlite"
    with Store(db) as store:
        job = Job(0, 1, load_cohort_params(None), False)  # `nod cohort --no-samples`
        store_session(store, job, simulate(job), "bare")
    with sqlite3.connect(db) as conn:
        assert conn.execute("SELECT COUNT(*) FROM samples").fetchone() == (0,)
    with open_stores([db]) as stores, union_of(stores) as conn:
        export_bids(conn, tmp_path / "ds", WithdrawnFilter({}))
    assert not (tmp_path / "ds" / "sub-P001" / "motion").exists()
    assert len(_tsv(tmp_path / "ds" / "sub-P001" / "beh" / "sub-P001_task-consensus_events.tsv"))


def test_each_sessions_provenance_is_in_its_sidecars(dataset: Path) -> None:
    expected = {"version": "1.2.3", "sources_sha256": "ab" * 32, "params_hash": "0123456789ab",
                "params_sha256": "cd" * 32, "study_name": "pilot", "study_sha256": "ef" * 32,
                "consent_version": "v2", "allocation_seed": 7, "preregistration": "osf.io/ab12c",
                "recording_sha256": "12" * 32}
    carried = {path.name: json.loads(path.read_text())["Provenance"]
               for path in dataset.rglob("*.json") if "Provenance" in json.loads(path.read_text())}
    # the one session with provenance: its beh and motion sidecars; the others have none
    assert sorted(n.rsplit("_", 1)[-1] for n in carried) == ["beh.json", "motion.json"]
    assert all(runs == [expected] for runs in carried.values())
    # no local path, host or wall-clock time leaves the store
    text = "".join(p.read_text() for p in dataset.rglob("*.json"))
    assert "/home/lab" not in text and "lab-pc1" not in text
    generated = json.loads((dataset / "dataset_description.json").read_text())["GeneratedBy"]
    assert [g["Name"] for g in generated] == ["nod-hri", "nod-hri"]
    assert generated[1]["Version"] == "1.2.3" and "ab" * 32 in generated[1]["Description"]
    people = _tsv(dataset / "participants.tsv")
    assert [p["consent_version"] for p in people].count("v2") == 1


def test_a_sessions_policy_and_estimates_are_its_beh_columns_and_csv_rows(
        dataset: Path, study: list[Path], tmp_path: Path) -> None:
    beh = _tsv(dataset / "sub-P001" / "beh" / "sub-P001_task-consensus_beh.tsv")
    assert [float(r["policy_b_star"]) for r in beh] == [SETTINGS[t].b_star for t in range(1, 9)]
    assert [float(r["estimate_speed"]) for r in beh] == [1.0 + t / 10 for t in range(1, 9)]
    assert {(r["estimate_contrarian_low"], r["estimate_contrarian_high"]) for r in beh} == {
        ("0.0", "1.0")}
    assert [r["estimate_trials_seen"] for r in beh] == [str(t) for t in range(1, 9)]
    other = _tsv(dataset / "sub-P002" / "beh" / "sub-P002_task-consensus_beh.tsv")
    assert not {"policy_b_star", "estimate_speed"} & set(other[0])  # the paper's robot
    args = [a for db in study for a in ("--db", str(db))]
    assert main([*args, "--out", str(tmp_path)]) == 0
    with (tmp_path / "policies.csv").open() as fh:
        policies = list(csv.DictReader(fh))
    assert [(r["participant"], r["policy"], float(r["b_star"])) for r in policies] == [
        ("P001", "mine", SETTINGS[t].b_star) for t in range(1, 9)]
    with (tmp_path / "estimates.csv").open() as fh:
        estimates = list(csv.DictReader(fh))
    assert len(estimates) == 16
    assert {r["probability"] for r in estimates if r["name"] == "contrarian"} == {"0.75"}
    assert {r["probability"] for r in estimates if r["name"] == "speed"} == {"NA"}
