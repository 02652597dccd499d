"""A participant who withdraws: left out of export, analysis and fit (one line naming them),
never run again, and with --delete every row and recording file of theirs gone — real SQLite
files, the commands' own entry points."""

from __future__ import annotations

import csv
import json
import sqlite3
import tempfile
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.analysis import cli as analyze
from services.experiment.export import main as export_main
from services.experiment.order import participant_problem
from services.fit.cli import main as fit_main
from services.fit.data import read_study
from services.model.protocol import default_schedule
from services.store import (
    CueRecord,
    Interruption,
    QuestionnaireRecord,
    SafetyEvent,
    Sample,
    Store,
    TrialRecord,
)
from services.store.fits import FitRecord, write_fits
from services.store.participants import next_free_ids, record_consent, record_order
from services.store.withdrawals import (
    delete_participant,
    operator_id,
    record_withdrawal,
    withdrawals,
    withdrawn,
)
from services.study import cli as study_cli
from services.study.studyfile import load, make_study, write

OUTCOMES = ("D", "C", "DH", "CH", "C", "D", "CH", "C")


def _trial(i: int, shift: int) -> TrialRecord:
    mode = "dissensus" if i <= 3 else "consensus"
    return TrialRecord(i, mode, None if i <= 3 else "red", "neutral", 0.0, 0.0, 10**9,
                       2 * 10**9, "red", "blue", OUTCOMES[(i + shift) % 8], 0, 0, 10, 0,
                       "human pressed")


def _hand(trial: int) -> list[Sample]:
    return [Sample(10**9 + k * 33_000_000, True, 0.5, 0.85 - 0.01 * k - 0.001 * trial, None,
                   None, None, None, None) for k in range(12)]


def _person(store: Store, pid: str, k: int, trials: int, status: str, rec_dir: Path) -> str:
    """A participant with a session, consent, order, answers, events, cues, a fit, a recording."""
    sid = f"s-{pid}"
    store.begin_session(sid, pid, "rig1", k, 10 * k, {})
    record_consent(store, pid, True, 10 * k, {"age": "25-34"})
    record_order(store, sid, pid, ("red", "blue", "blue", "red", "blue"), None, 10 * k)
    for i in range(1, trials + 1):
        events = [SafetyEvent(i, 1, 10 * k + i, "actuation", "safe_stop", "test")]
        cues = [CueRecord(i, 1, "go", 10 * k + i, 10 * k + i + 1)]
        store.write_trial(sid, _trial(i, k), _hand(i), events, cues)
    store.write_interruption(sid, Interruption(1, 1, 10 * k, 10 * k + 1, "estop"))
    store.begin_attempt(sid, trials + 1, 1, 10 * k + 50)
    if status != "running":
        store.finish_session(sid, 10 * k + 99, status)
    store.write_questionnaire(QuestionnaireRecord(pid, 1 + k, 9 - k, "Yes", 5, 6), 1, "test")
    write_fits(store, [FitRecord(pid, sid, "u", 0.1 * k, 0.0, 1.0, 0.9, "test", 1)])
    mcap = rec_dir / f"{pid}.mcap"
    mcap.write_bytes(b"\x89MCAP0\r\n" + pid.encode())
    store.add_recording(sid, mcap, 10 * k)
    return sid


@pytest.fixture
def study(tmp_path: Path) -> tuple[Path, Path]:
    """Six slots: P01-P04 complete (8 trials), P05 aborted after 3, P06 left; P02 also ran a
    three-option session and shares a recording with P03."""
    path, db = tmp_path / "study.toml", tmp_path / "s.sqlite"
    write(make_study("pilot", default_schedule(), 6, seed=4), path)
    store = Store(db)
    for k, pid in enumerate(("P01", "P02", "P03", "P04"), start=1):
        _person(store, pid, k, 8, "complete", tmp_path)
    _person(store, "P05", 5, 3, "aborted", tmp_path)
    store.begin_session("o-P02", "P02", "rig1", 2, 500, {}, ("a", "b", "c"))
    store.write_trial("o-P02", TrialRecord(1, "consensus", "a", "low", 0.1, 0.0, 1, 2, "a",
                                           "b", "D", 0, 0, None, 0, "human pressed"), ())
    shared = tmp_path / "shared.mcap"
    shared.write_bytes(b"both")
    store.add_recording("s-P02", shared, 1)
    store.add_recording("s-P03", shared, 1)
    store.close()
    return path, db


def _csv_participants(out: Path) -> dict[str, set[str]]:
    """Per CSV file, every participant named in it (by column, or by a session's owner)."""
    with (out / "sessions.csv").open() as fh:
        owner = {r["session"]: r["participant"] for r in csv.DictReader(fh)}
    found: dict[str, set[str]] = {}
    for f in sorted(out.glob("*.csv")):
        with f.open() as fh:
            rows = list(csv.DictReader(fh))
        if rows and not {"participant", "session"} & set(rows[0]):
            continue  # the anonymous aggregates: nobody's
        found[f.stem] = {r["participant"] if "participant" in r else owner.get(r["session"], "?")
                         for r in rows}
    return found


def _line(text: str, needle: str) -> str:
    lines = [ln for ln in text.splitlines() if needle in ln]
    assert len(lines) == 1, text
    return lines[0]


def _withdraw(path: Path, db: Path, pid: str, *flags: str) -> int:
    return study_cli.main(["withdraw", str(path), "--db", str(db), "--participant", pid, *flags])


def test_a_withdrawn_participant_is_left_out_of_the_export(study, tmp_path, capsys):
    path, db = study
    assert _withdraw(path, db, "P02", "--reason", "changed their mind") == 0
    assert "P02: withdrawn" in capsys.readouterr().out
    out = tmp_path / "csv"
    assert export_main(["--db", str(db), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert _line(printed, "left out (withdrawn)").endswith(
        "left out (withdrawn): P02; --include-withdrawn keeps them")
    seen = _csv_participants(out)
    assert {"trials", "samples", "cues", "fits", "participants"} <= set(seen)
    assert all("P02" not in who for who in seen.values()), seen
    assert seen["trials"] == {"P01", "P03", "P04", "P05"}
    assert seen["participants"] == {"P01", "P03", "P04", "P05"}
    # --include-withdrawn: back, and participants.csv says when they withdrew and why
    everyone = tmp_path / "all"
    assert export_main(["--db", str(db), "--out", str(everyone), "--include-withdrawn"]) == 0
    assert "included although withdrawn (--include-withdrawn): P02" in capsys.readouterr().out
    seen = _csv_participants(everyone)
    assert "P02" in seen["trials"] and "P02" in seen["samples"]
    with (everyone / "sessions.csv").open() as fh:
        sets = {r["session"]: r["options"] for r in csv.DictReader(fh)}
    assert sets["o-P02"] == '["a", "b", "c"]' and sets["s-P01"] == '["red", "blue"]'

    with (everyone / "participants.csv").open() as fh:
        rows = {r["participant"]: r for r in csv.DictReader(fh)}
    assert rows["P02"]["consent"] == "1"
    assert rows["P02"]["withdrawal_reason"] == "changed their mind"
    assert rows["P02"]["withdrawal_deleted"] == "0" and rows["P01"]["withdrawn_ns"] == "NA"
    assert json.loads(rows["P01"]["demographics"]) == {"age": "25-34"}


def test_a_withdrawn_participant_is_left_out_of_analyze_study(study, capsys):
    path, db = study
    assert _withdraw(path, db, "P03") == 0
    capsys.readouterr()
    assert analyze.main(["study", "--db", str(db), "--json"]) == 0
    got = capsys.readouterr()
    doc = json.loads(got.out)
    assert sorted(doc["grid"]) == ["P01", "P02", "P04"]
    assert [s["participant"] for s in doc["sessions"]] == ["P01", "P02", "P04"]
    # the aborted one and P02's unfinished three-option session, not P03
    assert {(e["participant"], e["session"]) for e in doc["excluded"]} == {
        ("P05", "s-P05"), ("P02", "o-P02")}
    assert doc["questionnaire"]["q1"]["n"] == 3  # P03's answers are theirs too
    assert "P03" not in doc["questionnaire_without_session"] + doc["questionnaire_excluded"]
    assert doc["withdrawn"]["left_out"] == ["P03"]
    err = got.err.strip()
    assert err == "nod analyze study: left out (withdrawn): P03; --include-withdrawn keeps them"
    assert analyze.main(["study", "--db", str(db), "--json", "--include-withdrawn"]) == 0
    got = capsys.readouterr()
    assert sorted(json.loads(got.out)["grid"]) == ["P01", "P02", "P03", "P04"]
    assert "included although withdrawn (--include-withdrawn): P03" in got.err


def test_the_fit_follows_the_inclusion_rule_and_leaves_the_withdrawn_out(study, capsys):
    path, db = study
    assert _withdraw(path, db, "P04") == 0
    fit = read_study(db)
    assert [p.participant for p in fit.people] == ["P01", "P02", "P03"]
    assert fit.notes == [
        "left out (withdrawn): P04; --include-withdrawn keeps them",
        "left out (inclusion rule: complete sessions only): P05 (aborted after 3 of 8 trials); "
        "--min-trials N fits sessions with at least N scored trials",
    ]
    assert [p.participant for p in read_study(db, include_withdrawn=True).people] == [
        "P01", "P02", "P03", "P04"]
    from services.analysis.sessions import InclusionRule

    lenient = read_study(db, rule=InclusionRule(3))
    assert [p.participant for p in lenient.people] == ["P01", "P02", "P03", "P05"]
    assert lenient.notes == ["left out (withdrawn): P04; --include-withdrawn keeps them"]
    capsys.readouterr()
    assert fit_main(["--db", str(db), "--participant", "P04"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("nod fit: error: participant 'P04' withdrew from the study: not fitted "
                   "(--include-withdrawn fits them)")


def _rows_of(db: Path, participant: str, sessions: set[str]) -> dict[str, int]:
    """Rows per table that are this participant's: by participant, else by session (raw SQL)."""
    con = sqlite3.connect(db)
    try:
        counts: dict[str, int] = {}
        tables = [r[0] for r in con.execute(
            "SELECT name FROM sqlite_master WHERE type = 'table' AND name != 'withdrawals'")]
        for t in tables:
            cols = {r[1] for r in con.execute(f'PRAGMA table_info("{t}")')}
            n = 0
            for row in con.execute(f'SELECT * FROM "{t}"'):
                rec = dict(zip([c[1] for c in con.execute(f'PRAGMA table_info("{t}")')], row,
                               strict=True))
                if ("participant" in cols and rec["participant"] == participant) or (
                        "session" in cols and rec["session"] in sessions):
                    n += 1
            if n:
                counts[t] = n
        return counts
    finally:
        con.close()


def _sessions(db: Path) -> dict[str, set[str]]:
    con = sqlite3.connect(db)
    try:
        out: dict[str, set[str]] = {}
        for s, p in con.execute("SELECT session, participant FROM sessions"):
            out.setdefault(p, set()).add(s)
        return out
    finally:
        con.close()


def test_delete_removes_every_row_and_recording_of_theirs_and_nothing_else(study, tmp_path,
                                                                           capsys):
    path, db = study
    owned = _sessions(db)
    before = {p: _rows_of(db, p, owned[p]) for p in owned}
    assert {"sessions", "trials", "samples", "safety_events", "interruptions", "cues",
            "open_attempts", "questionnaires", "recordings", "participants", "session_orders",
            "fits", "option_sets"} <= set(before["P02"])
    Store(db).backup()  # a backup made before: it is rewritten without them
    assert _withdraw(path, db, "P02", "--delete", "--dry-run") == 0
    assert "would delete" in capsys.readouterr().out and _rows_of(db, "P02", owned["P02"])
    assert _withdraw(path, db, "P02", "--reason", "private detail", "--delete") == 0
    line = _line(capsys.readouterr().out, "P02: withdrawn, data deleted in one transaction")
    assert "1 recording file(s) deleted" in line and "1 kept (another session's too" in line
    after = {p: _rows_of(db, p, owned[p]) for p in owned}
    assert after["P02"] == {}
    assert {p: c for p, c in after.items() if p != "P02"} == {
        p: c for p, c in before.items() if p != "P02"}
    assert not (tmp_path / "P02.mcap").exists()
    assert (tmp_path / "P03.mcap").exists() and (tmp_path / "shared.mcap").exists()
    store = Store(db)
    w = withdrawals(store)["P02"]
    assert w.deleted and w.reason == "" and w.deleted_ns is not None
    removed = {k: v for k, v in w.counts.items() if k != "recording_files"}
    expected = dict(before["P02"])
    assert removed == expected and w.counts["recording_files"] == 1
    assert next_free_ids(store, 1) == ["P06"]  # P02's id stays taken
    store.close()
    backup = sqlite3.connect(db.with_name(db.name + ".backup"))
    assert backup.execute("SELECT COUNT(*) FROM samples WHERE session = 's-P02'").fetchone() == (0,)
    backup.close()
    out = tmp_path / "csv"
    assert export_main(["--db", str(db), "--out", str(out), "--include-withdrawn"]) == 0
    assert "included although withdrawn (--include-withdrawn): P02 (deleted)" in (
        capsys.readouterr().out)
    seen = _csv_participants(out)
    assert all("P02" not in who for name, who in seen.items() if name != "participants")
    with (out / "participants.csv").open() as fh:
        p02 = next(r for r in csv.DictReader(fh) if r["participant"] == "P02")
    assert p02["consent"] == "NA" and p02["withdrawal_deleted"] == "1"
    assert _withdraw(path, db, "P02", "--delete") == 0  # twice: nothing left to do
    assert "nothing left to do" in capsys.readouterr().out


def test_status_start_and_consent_treat_the_withdrawn_as_gone(study, capsys):
    path, db = study
    store = Store(db)
    record_withdrawal(store, "P05", 1, "")  # aborted: would be offered a resume
    store.close()
    assert study_cli.main(["status", str(path), "--db", str(db)]) == 0
    out = capsys.readouterr().out
    p05 = _line(out, " P05 ")
    assert "withdrawn" in p05 and "resume" not in p05 and "data kept, left out" in p05
    assert "resume" not in out  # nobody else is running or aborted
    assert "1 withdrawn; next: P06" in out
    assert study_cli.main(["status", str(path), "--db", str(db), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["participants"][4]["status"] == "withdrawn" and doc["counts"]["withdrawn"] == 1
    assert doc["participants"][4]["withdrawn"]["deleted"] is False
    for flags in (["--participant", "P05"], ["--participant", "P05", "--again", "retry"]):
        assert study_cli.main(["start", str(path), "--db", str(db), "--dry-run", *flags]) == 2
        assert "participant P05 withdrew from the study" in capsys.readouterr().err
    assert study_cli.main(["consent", str(path), "--db", str(db), "--participant", "P05",
                           "--yes"]) == 2
    assert "P05 withdrew" in capsys.readouterr().err
    store = Store(db)
    assert participant_problem(store, "P05", None, None) is not None
    assert participant_problem(store, "P05", "again", None) is not None
    assert participant_problem(store, "x", None, "s-P05") is not None  # no resume either
    assert participant_problem(store, "x", None, "s-P01") is None
    store.close()


def test_consent_no_after_consent_follows_the_studys_policy(study, tmp_path, capsys):
    path, db = study
    text = path.read_text()
    assert 'on_withdrawal = "keep"' in text
    path.write_text(text.replace('on_withdrawal = "keep"', 'on_withdrawal = "delete"'))
    assert load(path).on_withdrawal == "delete"
    assert study_cli.main(["consent", str(path), "--db", str(db), "--participant", "P01",
                           "--no"]) == 0
    assert "P01: withdrawn, data deleted" in capsys.readouterr().out
    assert study_cli.main(["consent", str(path), "--db", str(db), "--participant", "P03",
                           "--no", "--keep"]) == 0
    assert "P03: withdrawn" in capsys.readouterr().out
    store = Store(db)
    got = withdrawals(store)
    assert got["P01"].deleted and not got["P03"].deleted and got["P03"].reason == (
        "consent withdrawn")
    assert "P01" not in _sessions(db) and "P03" in _sessions(db)
    store.close()
    path.write_text(text.replace('on_withdrawal = "keep"', 'on_withdrawal = "maybe"'))
    assert study_cli.main(["status", str(path), "--db", str(db)]) == 2
    assert "on_withdrawal must be one of ('keep', 'delete', 'aggregate')" in capsys.readouterr().err


def test_an_older_store_without_the_table_opens_and_has_nobody_withdrawn(tmp_path):
    db = tmp_path / "old.sqlite"
    Store(db).close()
    con = sqlite3.connect(db)
    con.execute("DROP TABLE withdrawals")
    con.commit()
    con.close()
    store = Store(db)
    assert withdrawn(store) == set()
    store.close()


@settings(max_examples=15, deadline=None)
@given(
    st.lists(st.integers(0, 3), min_size=2, max_size=5),  # trials per participant
    st.data(),
)
def test_deleting_any_participants_leaves_everyone_elses_rows(trials: list[int], data) -> None:
    ids = [f"P{k + 1:02d}" for k in range(len(trials))]
    gone = data.draw(st.sets(st.sampled_from(ids), max_size=len(ids) - 1))
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        db = folder / "s.sqlite"
        store = Store(db)
        for k, (pid, n) in enumerate(zip(ids, trials, strict=True), start=1):
            _person(store, pid, k, n, "aborted", folder)
        store.close()
        owned = _sessions(db)
        before = {p: _rows_of(db, p, owned[p]) for p in ids}
        store = Store(db)
        for pid in sorted(gone):
            d = delete_participant(store, pid, 7)
            assert d.removed == [folder / f"{pid}.mcap"]
        store.close()
        after = {p: _rows_of(db, p, owned[p]) for p in ids}
        for pid in ids:
            assert after[pid] == ({} if pid in gone else before[pid])
            assert (folder / f"{pid}.mcap").exists() == (pid not in gone)


def _aggregates(db: Path) -> list[tuple]:
    con = sqlite3.connect(db)
    try:
        return list(con.execute("SELECT options, trial, mode, outcome, n FROM withdrawn_aggregates "
                                "ORDER BY options, trial, outcome"))
    finally:
        con.close()


def test_aggregate_keeps_only_anonymous_outcome_counts_and_logs_who(study, tmp_path, capsys):
    """--aggregate (or on_withdrawal = "aggregate"): their trials' outcomes are added to the
    study's per-trial counts, then every row and file of theirs goes as with --delete."""
    path, db = study
    owned = _sessions(db)
    assert _withdraw(path, db, "P04", "--keep") == 0  # kept first: logged with who did it
    with Store(db) as store:
        assert withdrawals(store)["P04"].by == operator_id() and "@" in operator_id()
    path.write_text(path.read_text().replace('on_withdrawal = "keep"',
                                             'on_withdrawal = "aggregate"'))
    assert load(path).on_withdrawal == "aggregate"
    assert _withdraw(path, db, "P01", "--dry-run") == 0
    assert "would add their trials to the anonymous counts and delete" in capsys.readouterr().out
    assert _withdraw(path, db, "P01", "--reason", "moved away") == 0
    line = _line(capsys.readouterr().out, "P01: withdrawn, data deleted in one transaction")
    assert "8 trial outcome(s) added to the anonymous counts" in line
    assert f"by {operator_id()}" in line
    assert _rows_of(db, "P01", owned["P01"]) == {} and not (tmp_path / "P01.mcap").exists()
    # P01's outcomes, shift 1: trial i has OUTCOMES[(i + 1) % 8], one each, with no id
    first = _aggregates(db)
    assert [(t, o, n) for _, t, _, o, n in first] == [
        (i, OUTCOMES[(i + 1) % 8], 1) for i in range(1, 9)]
    assert {opts for opts, *_ in first} == {'["red", "blue"]'}
    assert _withdraw(path, db, "P03", "--aggregate") == 0  # a second one adds to the counts
    capsys.readouterr()
    both = _aggregates(db)
    assert sum(n for *_, n in both) == 16 and sum(n for _, t, _, _, n in both if t == 5) == 2
    with Store(db) as store:
        w = withdrawals(store)
    assert w["P01"].aggregated and w["P01"].deleted and w["P01"].counts["aggregate_trials"] == 8
    assert w["P01"].reason == "" and w["P01"].by == operator_id()
    assert not w["P04"].aggregated and not w["P04"].deleted
    out = tmp_path / "csv"
    assert export_main(["--db", str(db), "--out", str(out)]) == 0
    seen = _csv_participants(out)
    assert all({"P01", "P03", "P04"}.isdisjoint(who) for who in seen.values()), seen
    with (out / "withdrawn_aggregates.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["options", "trial", "mode", "outcome", "n"]
    assert sum(int(r["n"]) for r in rows) == 16


def test_delete_takes_their_real_recording_and_its_provenance_with_them(study, tmp_path, capsys):
    from mcap.reader import make_reader

    from services.core.provenance import PROVENANCE_METADATA, make_provenance, metadata
    from services.recording.mcap_io import FILE_METADATA, McapOut
    from services.store.provenance import finish_provenance, read_provenance, write_provenance

    path, db = study
    rec_dir = tmp_path / "recordings"
    rec_dir.mkdir()
    prov = make_provenance("1", "0123456789ab")
    with Store(db) as store:
        for pid in ("P02", "P04"):
            sid = f"s-{pid}"
            mcap = rec_dir / f"{sid}.mcap"
            out = McapOut(mcap)
            out.metadata(FILE_METADATA, {"rig": "rig1", "session": sid})
            out.metadata(PROVENANCE_METADATA, metadata(prov, sid))
            out.finish()
            store.add_recording(sid, mcap, 5)
            write_provenance(store, sid, 5, prov)
            finish_provenance(store, sid, 5, 6, {"decision": ("pc",)}, mcap)
    with (rec_dir / "s-P04.mcap").open("rb") as fh:  # a real MCAP file, read by mcap's reader
        assert {m.name for m in make_reader(fh).iter_metadata()} == {"nod", PROVENANCE_METADATA}
    assert _withdraw(path, db, "P02", "--delete") == 0
    line = _line(capsys.readouterr().out, "P02: withdrawn, data deleted")
    assert "1 provenance" in line and "2 recording file(s) deleted" in line
    assert not (rec_dir / "s-P02.mcap").exists() and (rec_dir / "s-P04.mcap").exists()
    with Store(db) as store:
        assert [r.session for r in read_provenance(store)] == ["s-P04"]
        assert withdrawals(store)["P02"].counts["provenance"] == 1
    out = tmp_path / "csv"
    assert export_main(["--db", str(db), "--out", str(out)]) == 0
    with (out / "provenance.csv").open() as fh:
        assert [r["participant"] for r in csv.DictReader(fh)] == ["P04"]
