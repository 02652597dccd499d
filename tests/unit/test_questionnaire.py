"""`nod questionnaire`: validation, prompting, CSV import (all or nothing) and the store table."""

from __future__ import annotations

import io
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.experiment.questionnaire import (
    QUESTIONS,
    CsvError,
    InputEndedError,
    main,
    parse_likert,
    parse_participant,
    parse_q3,
    prompt_answers,
    read_csv,
    write_csv,
)
from services.store import QuestionnaireRecord, Store

ROOT = Path(__file__).resolve().parents[2]
HEADER = "participant,q1,q2,q3,q4,q5\n"

participants = st.from_regex(r"\A[A-Za-z0-9][A-Za-z0-9_.-]{0,12}\Z").filter(
    lambda p: p.upper() not in {"NA", "NAN", "NULL"}
)
likert = st.integers(1, 10)
records = st.builds(
    QuestionnaireRecord,
    participants,
    likert,
    likert,
    st.sampled_from(["Yes", "No", "Maybe"]),
    likert,
    likert,
)


@given(st.integers(-1000, 1000))
def test_likert_accepts_exactly_1_to_10(n: int) -> None:
    if 1 <= n <= 10:
        assert parse_likert(f" {n} \n") == n
    else:
        with pytest.raises(ValueError, match="1 to 10"):
            parse_likert(str(n))


@pytest.mark.parametrize("text", ["", "7.5", "seven", "1e1", "0x5", "5 5"])
def test_likert_rejects_non_integers(text: str) -> None:
    with pytest.raises(ValueError, match="whole number"):
        parse_likert(text)


def test_q3_and_participant() -> None:
    assert [parse_q3(t) for t in ("yes", " NO ", "Maybe\n")] == ["Yes", "No", "Maybe"]
    with pytest.raises(ValueError, match="Yes, No or Maybe"):
        parse_q3("y")
    assert parse_participant(" P07 ") == "P07"
    for bad in ("", "P 1", "-x", "NA"):
        with pytest.raises(ValueError):
            parse_participant(bad)


def test_questions_are_the_papers_five() -> None:
    assert [q.key for q in QUESTIONS] == ["q1", "q2", "q3", "q4", "q5"]
    assert [q.likert for q in QUESTIONS] == [True, True, False, True, True]
    assert "first three" in QUESTIONS[0].text and "clicker" in QUESTIONS[2].text


def test_prompt_reasks_until_valid() -> None:
    lines = iter(["3\n", "0\n", "eleven\n", "8\n", "perhaps\n", "MAYBE\n", "6\n", "9\n"])
    out = io.StringIO()
    rec = prompt_answers("P01", lambda: next(lines), out.write)
    assert rec == QuestionnaireRecord("P01", 3, 8, "Maybe", 6, 9)
    assert out.getvalue().count("invalid") == 3 and out.getvalue().count("Q2> ") == 3


def test_prompt_eof_names_the_question() -> None:
    lines = iter(["3\n", "4\n", ""])
    with pytest.raises(InputEndedError, match="before Q3"):
        prompt_answers("P01", lambda: next(lines), lambda s: None)


@settings(max_examples=40)
@given(st.lists(records, min_size=1, max_size=12, unique_by=lambda r: r.participant))
def test_csv_round_trip(recs: list[QuestionnaireRecord]) -> None:
    buf = io.StringIO()
    write_csv(recs, buf)
    assert read_csv(io.StringIO(buf.getvalue())) == recs


def test_csv_any_column_order_and_case() -> None:
    text = "Q3,participant,q5,q4,q2,q1\nno,P02,1,2,3,4\n\nMaybe,P03,10,9,8,7\n"
    assert read_csv(io.StringIO(text)) == [
        QuestionnaireRecord("P02", 4, 3, "No", 2, 1),
        QuestionnaireRecord("P03", 7, 8, "Maybe", 9, 10),
    ]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty file"),
        (HEADER, "no answers"),
        ("participant,q1,q2,q3,q4\nP01,1,2,Yes,4\n", "line 1: .*missing q5"),
        (HEADER.replace("\n", ",age\n") + "P01,1,2,Yes,4,5,30\n", "unknown 'age'"),
        (HEADER + "P01,1,2,Yes,4,5\nP02,1,2,Yes,4,11\n", "line 3, column q5: .*got 11"),
        (HEADER + "P01,1,2,Yes,4,5\nP01,1,2,No,4,5\n", "line 3, column participant: .*line 2"),
        (HEADER + "P01,1,2,Sometimes,4,5\n", "line 2, column q3: expected Yes, No or Maybe"),
        (HEADER + "P01,1,2,Yes\n", "line 2: expected 6 columns"),
        (HEADER + "P01,1,2,Yes,4,5,6\n", "line 2: expected 6 columns"),
        (HEADER + "P 1,1,2,Yes,4,5\n", "line 2, column participant"),
    ],
)
def test_csv_errors_name_line_and_column(text: str, message: str) -> None:
    with pytest.raises(CsvError, match=message):
        read_csv(io.StringIO(text), "answers.csv")


def test_import_is_all_or_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db, csv_path = tmp_path / "s.db", tmp_path / "answers.csv"
    csv_path.write_text(HEADER + "P01,1,2,Yes,4,5\nP02,3,4,No,5,x\n")
    assert main(["--db", str(db), "--import", str(csv_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "line 3, column q5" in err and "nothing stored" in err
    store = Store(db)
    assert store.questionnaires() == []
    store.close()
    csv_path.write_text("\ufeff" + HEADER + "P01,1,2,Yes,4,5\nP02,3,4,No,5,6\n")  # Excel BOM
    assert main(["--db", str(db), "--import", str(csv_path)]) == 0
    assert "no session yet for P01, P02" in capsys.readouterr().err
    # P02 again, with a new participant: refused as a whole without --replace.
    csv_path.write_text(HEADER + "P03,1,1,Maybe,1,1\nP02,9,9,Yes,9,9\n")
    assert main(["--db", str(db), "--import", str(csv_path)]) == 2
    assert "already stored for P02" in capsys.readouterr().err
    store = Store(db)
    assert [r.participant for r in store.questionnaires()] == ["P01", "P02"]
    store.close()
    assert main(["--db", str(db), "--import", str(csv_path), "--replace"]) == 0
    store = Store(db)
    assert store.questionnaires()[1:] == [
        QuestionnaireRecord("P02", 9, 9, "Yes", 9, 9),
        QuestionnaireRecord("P03", 1, 1, "Maybe", 1, 1),
    ]
    rows = store.db.execute("SELECT participant, source FROM questionnaires").fetchall()
    assert ("P03", "csv:answers.csv") in rows
    store.close()


def test_store_rejects_out_of_range_values(tmp_path: Path) -> None:
    store = Store(tmp_path / "s.db")
    with pytest.raises(sqlite3.IntegrityError):
        store.write_questionnaire(QuestionnaireRecord("P01", 0, 5, "Yes", 5, 5), 0, "test")
    with pytest.raises(ValueError, match="more than once"):
        store.write_questionnaires([QuestionnaireRecord("P01", 1, 5, "Yes", 5, 5)] * 2, 0, "t")
    assert store.questionnaires() == []
    store.close()


def _nod(*args: str, stdin: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "services.cli", "questionnaire", *args],
        cwd=ROOT,
        input=stdin,
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_cli_prompts_on_stdin(tmp_path: Path) -> None:
    db = str(tmp_path / "s.db")
    res = _nod("--db", db, "--participant", "P04", stdin="2\n7\nx\nyes\n6\n10\n")
    assert res.returncode == 0, res.stderr
    assert "Working against me" in res.stdout and "invalid" in res.stdout
    res = _nod("--db", db, "--participant", "P05", stdin="2\n7\n")
    assert res.returncode == 1
    assert res.stderr.strip() == (
        "nod questionnaire: aborted: input ended before Q3 was answered; nothing stored for P05"
    )
    store = Store(db)
    assert store.questionnaires() == [QuestionnaireRecord("P04", 2, 7, "Yes", 6, 10)]
    store.close()
    res = _nod("--db", db, stdin="")
    assert res.returncode == 2 and res.stderr.count("\n") == 1


def test_nod_lists_the_new_commands() -> None:
    from services.cli import COMMANDS

    assert COMMANDS["questionnaire"] == (
        "services.experiment.questionnaire",
        "enter or import Q1-Q5 answers",
    )
    assert COMMANDS["export"] == ("services.experiment.export", "write a session database as CSV")
