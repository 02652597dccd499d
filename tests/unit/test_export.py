"""`nod export`: every table as CSV, read back with the csv module, equals the database."""

from __future__ import annotations

import csv
import sqlite3
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.experiment.export import MISSING, main
from services.store import QuestionnaireRecord, Sample, Store, TrialRecord

ROOT = Path(__file__).resolve().parents[2]
TABLES = ("sessions", "trials", "samples", "questionnaires")


def _trial(n: int, outcome: str | None) -> TrialRecord:
    return TrialRecord(
        trial=n,
        mode="dissensus" if n <= 3 else "consensus",
        option=None if n <= 3 else "red",
        gaze_level="neutral",
        yaw=0.1 * n,
        pitch=-1 / 3,
        t_go_ns=None if outcome is None else 10**12 + n,
        t_end_ns=None,
        human=None if outcome is None else "red",
        robot="blue",
        outcome=outcome,
        switches=n % 2,
        violations=0,
        clicks=None,
        score=-1,
        end_reason="timeout" if outcome is None else "human pressed",
    )


def _build(path: Path, samples: list[Sample]) -> None:
    store = Store(path)
    store.begin_session("a", "P01", "rig, with comma", 3, 5, {"note": 'quote " and\nnewline'})
    store.write_trial("a", _trial(1, "D"), samples)
    store.write_trial("a", _trial(2, None), [])
    store.finish_session("a", 9)
    store.begin_session("b", "P02", "sim", None, 7, {})
    store.write_trial("b", _trial(4, "CH"), samples[:1])
    store.write_questionnaires(
        [QuestionnaireRecord("P01", 1, 10, "Maybe", 5, 6)], 123456789012345678, "prompt"
    )
    store.close()


def _expected(path: Path, table: str) -> tuple[list[str], list[tuple]]:
    from services.experiment.export import QUERIES

    db = sqlite3.connect(path)
    cur = db.execute(QUERIES[table])
    header, rows = [c[0] for c in cur.description], cur.fetchall()
    db.close()
    return header, rows


def _read_back(field: str, like: object) -> object:
    """Parse a CSV field as the type of the database value it should equal."""
    if field == MISSING:
        return None
    if isinstance(like, bool | int):
        return int(field)
    if isinstance(like, float):
        return float(field)
    return field


def _check(db: Path, out: Path) -> None:
    for table in TABLES:
        header, rows = _expected(db, table)
        with (out / f"{table}.csv").open(newline="", encoding="utf-8") as fh:
            got = list(csv.reader(fh))
        assert got[0] == header
        assert len(got) - 1 == len(rows)
        for line, row in zip(got[1:], rows, strict=True):
            assert [_read_back(f, v) for f, v in zip(line, row, strict=True)] == list(row)


SAMPLE = Sample(1, True, 0.1, None, 1 / 3, -2.5e-300, 7.0, None, 123456.789)


def test_export_round_trip(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db, out = tmp_path / "s.db", tmp_path / "csv"
    _build(db, [SAMPLE, Sample(2, False, None, None, None, None, None, None, None)])
    assert main(["--db", str(db), "--out", str(out)]) == 0
    assert "trials.csv: 3 rows" in capsys.readouterr().out
    _check(db, out)
    trials = list(csv.DictReader((out / "trials.csv").open()))
    assert [(t["session"], t["participant"], t["outcome"]) for t in trials] == [
        ("a", "P01", "D"),
        ("a", "P01", MISSING),
        ("b", "P02", "CH"),
    ]
    sessions = list(csv.DictReader((out / "sessions.csv").open(newline="")))
    assert sessions[0]["rig"] == "rig, with comma" and "newline" in sessions[0]["config"]
    assert sessions[1]["seed"] == MISSING and sessions[1]["status"] == "running"


finite = st.floats(allow_nan=False, allow_infinity=False)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(finite, st.none() | finite, st.booleans()), min_size=1, max_size=20))
def test_samples_round_trip_exactly(values: list[tuple]) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        db, out = Path(tmp) / "s.db", Path(tmp) / "out"
        samples = [Sample(i, d, x, y, x, y, x, y, x) for i, (x, y, d) in enumerate(values)]
        _build(db, samples)
        assert main(["--db", str(db), "--out", str(out)]) == 0
        _check(db, out)
        with (out / "samples.csv").open(newline="") as fh:
            rows = list(csv.DictReader(fh))
    first = [r for r in rows if r["session"] == "a"]
    assert [float(r["hand_x"]) for r in first] == [v[0] for v in values]
    assert [r["hand_y"] == MISSING for r in first] == [v[1] is None for v in values]
    assert [r["detected"] for r in first] == [str(int(v[2])) for v in values]


def test_errors_are_one_line(tmp_path: Path) -> None:
    res = subprocess.run(
        [sys.executable, "-m", "services.cli", "export", "--db", str(tmp_path / "x.db")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "--out" in res.stderr
    assert main(["--db", str(tmp_path / "missing.db"), "--out", str(tmp_path)]) == 2
    assert not (tmp_path / "missing.db").exists()


@given(
    st.lists(
        st.tuples(st.floats(-0.5, 1.5, width=32), st.floats(-0.5, 1.5, width=32)), max_size=64
    )
)
def test_landmarks_pack_and_unpack_exactly(points):
    from services.store import pack_landmarks, unpack_landmarks

    blob = pack_landmarks(points)
    assert len(blob) == 8 * len(points)
    assert unpack_landmarks(blob) == tuple(points)  # float32 values survive bit for bit


def test_landmarks_are_stored_and_exported(tmp_path):
    from services.store import pack_landmarks, unpack_landmarks

    hand = [(0.25, 0.75), (0.5, 0.125)]
    db = tmp_path / "l.sqlite"
    _build(db, [Sample(1, True, 0.375, 0.4375, None, None, None, None, None, 0.5, 0.25,
                       pack_landmarks(hand)), Sample(2, False, None, None, None, None, None,
                                                     None, None)])
    store = Store(db)
    try:
        got = store.samples("a", 1)
    finally:
        store.close()
    assert unpack_landmarks(got[0].landmarks) == tuple(hand) and got[1].landmarks is None
    out = tmp_path / "csv"
    assert main(["--db", str(db), "--out", str(out)]) == 0
    rows = [r for r in csv.DictReader((out / "samples.csv").open()) if r["session"] == "a"]
    assert rows[0]["landmarks"] == "0.25 0.75 0.5 0.125" and rows[1]["landmarks"] == "NA"
    with pytest.raises(ValueError, match="whole number of points"):
        unpack_landmarks(b"\x00" * 12)
