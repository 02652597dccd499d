"""`nod questionnaire`: the post-session questions Q1-Q5 of paper Sec 8, entered or imported.

Q1, Q2, Q4 and Q5 are Likert ratings from 1 to 10 (whole numbers); Q3 is Yes, No or Maybe
(any letter case; stored as 'Yes', 'No', 'Maybe'). Answers are stored per participant in the
session database's `questionnaires` table.

- `nod questionnaire --db FILE --participant P01` asks each question on stdin, one line per
  answer, and asks again after an invalid one; end of input aborts with nothing stored.
- `nod questionnaire --db FILE --import answers.csv` reads a CSV with the header
  `participant,q1,q2,q3,q4,q5` (any column order). Every row is validated first; the first bad
  row is reported as one line naming its line number and column, and nothing is stored.

A participant who already has answers is refused unless `--replace` is given.
"""

from __future__ import annotations

import argparse
import csv
import re
import sqlite3
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from services.core.cli import Parser, fail
from services.store import QuestionnaireRecord, Store

PROG = "nod questionnaire"
LIKERT_MIN, LIKERT_MAX = 1, 10
Q3_CHOICES: tuple[str, ...] = ("Yes", "No", "Maybe")
COLUMNS: tuple[str, ...] = ("participant", "q1", "q2", "q3", "q4", "q5")
_PARTICIPANT = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


@dataclass(frozen=True, slots=True)
class Question:
    """One question of Sec 8: its column, text and the meaning of its scale."""

    key: str  # column name: q1 … q5
    text: str  # as printed in the paper
    scale: str  # the answer format shown to the participant

    @property
    def likert(self) -> bool:
        """True for the 1-10 ratings, False for Q3 (Yes/No/Maybe)."""
        return self.key != "q3"


QUESTIONS: tuple[Question, ...] = (
    Question(
        "q1",
        "Did you feel the robot was working with you or against you during the first three "
        "(initial) trials?",
        "1 = Working against me, 10 = Working with me",
    ),
    Question(
        "q2",
        "Did you take visual hints provided by the robotic eye?",
        "1 = Not at all, 10 = Very heavily",
    ),
    Question(
        "q3",
        "Did the clicker placed behind you cause a split in your attention or slow your responses?",
        "Yes / No / Maybe",
    ),
    Question(
        "q4",
        "Did you perceive that the robotic eye's hints varied noticeably across iterations, "
        "becoming more pronounced in the final trials?",
        "1 = Not at all, 10 = Very heavily",
    ),
    Question(
        "q5",
        "By the end (trials 4-8), did you feel the robot was working collaboratively with you?",
        "1 = Working against me, 10 = Working with me",
    ),
)


def parse_likert(text: str) -> int:
    """A Likert rating: a whole number 1-10 (surrounding blanks ignored); ValueError otherwise."""
    value = text.strip()
    if not re.fullmatch(r"[+]?\d+", value):
        raise ValueError(f"expected a whole number from 1 to 10, got {text.strip()!r}")
    number = int(value)
    if not LIKERT_MIN <= number <= LIKERT_MAX:
        raise ValueError(f"expected a whole number from 1 to 10, got {number}")
    return number


def parse_q3(text: str) -> str:
    """Q3's answer as 'Yes', 'No' or 'Maybe' (any case, blanks ignored); ValueError otherwise."""
    value = text.strip().lower()
    for choice in Q3_CHOICES:
        if value == choice.lower():
            return choice
    raise ValueError(f"expected Yes, No or Maybe, got {text.strip()!r}")


def parse_participant(text: str) -> str:
    """A participant id such as P01: letters, digits, '_', '.', '-' (at most 64 characters)."""
    value = text.strip()
    if value.upper() in {"NA", "NAN", "NULL"}:
        raise ValueError(f"{value!r} reads as a missing value in R and pandas; use e.g. P01")
    if not _PARTICIPANT.fullmatch(value):
        raise ValueError(
            f"expected a participant id like P01 (letters, digits, _ . -), got {text.strip()!r}"
        )
    return value


def parse_answer(question: Question, text: str) -> int | str:
    """One answer, validated for its question."""
    return parse_likert(text) if question.likert else parse_q3(text)


def record_from_answers(participant: str, answers: Mapping[str, int | str]) -> QuestionnaireRecord:
    """A record from already parsed answers keyed q1 … q5."""
    return QuestionnaireRecord(
        participant=participant,
        q1=int(answers["q1"]),
        q2=int(answers["q2"]),
        q3=str(answers["q3"]),
        q4=int(answers["q4"]),
        q5=int(answers["q5"]),
    )


class InputEndedError(Exception):
    """Standard input ended before every question was answered."""


def prompt_answers(
    participant: str,
    read_line: Callable[[], str],
    write: Callable[[str], object],
) -> QuestionnaireRecord:
    """Ask Q1-Q5 one line at a time; re-ask after an invalid answer.

    `read_line` returns one line including its newline, or '' at end of input (like
    `TextIO.readline`); end of input raises InputEndedError naming the unanswered question.
    """
    answers: dict[str, int | str] = {}
    for number, question in enumerate(QUESTIONS, start=1):
        write(f"Q{number}. {question.text}\n    ({question.scale})\n")
        while True:
            write(f"Q{number}> ")
            line = read_line()
            if line == "":
                raise InputEndedError(f"input ended before Q{number} was answered")
            try:
                answers[question.key] = parse_answer(question, line)
                break
            except ValueError as exc:
                write(f"  invalid: {exc}; please answer again\n")
    return record_from_answers(participant, answers)


class CsvError(ValueError):
    """A CSV file that cannot be imported; the message names the line and the column."""


def read_csv(lines: Iterable[str], name: str = "CSV") -> list[QuestionnaireRecord]:
    """Validate every row of a `participant,q1,q2,q3,q4,q5` CSV; CsvError on the first bad one.

    Line numbers count the header as line 1. Blank lines are skipped; duplicate participants,
    missing or unknown columns, and an empty file are errors.
    """
    reader = csv.DictReader(lines)
    header = [(h or "").strip().lower() for h in (reader.fieldnames or [])]
    if not header:
        raise CsvError(f"{name}: empty file; expected the header {','.join(COLUMNS)}")
    problems = [f"missing {c}" for c in COLUMNS if c not in header]
    problems += [f"unknown {h!r}" for h in dict.fromkeys(header) if h not in COLUMNS]
    problems += [f"repeated {h}" for h in dict.fromkeys(header) if header.count(h) > 1]
    if problems:
        raise CsvError(
            f"{name} line 1: header must be {','.join(COLUMNS)} (any order): {', '.join(problems)}"
        )
    reader.fieldnames = header
    records: list[QuestionnaireRecord] = []
    seen: dict[str, int] = {}
    for row in reader:
        line = reader.line_num
        if None in row or any(row.get(c) is None for c in COLUMNS):
            raise CsvError(f"{name} line {line}: expected {len(COLUMNS)} columns")
        try:
            participant = parse_participant(row["participant"])
        except ValueError as exc:
            raise CsvError(f"{name} line {line}, column participant: {exc}") from None
        if participant in seen:
            raise CsvError(
                f"{name} line {line}, column participant: {participant} already given on "
                f"line {seen[participant]}"
            )
        seen[participant] = line
        answers: dict[str, int | str] = {}
        for question in QUESTIONS:
            try:
                answers[question.key] = parse_answer(question, row[question.key])
            except ValueError as exc:
                raise CsvError(f"{name} line {line}, column {question.key}: {exc}") from None
        records.append(record_from_answers(participant, answers))
    if not records:
        raise CsvError(f"{name}: no answers below the header")
    return records


def write_csv(records: Iterable[QuestionnaireRecord], out: TextIO) -> None:
    """Write records in the import format (the inverse of read_csv)."""
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(COLUMNS)
    for r in records:
        writer.writerow([r.participant, r.q1, r.q2, r.q3, r.q4, r.q5])


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod questionnaire`."""
    p = Parser(
        prog=PROG,
        description="Enter (prompted, on stdin) or import (CSV) the Sec 8 questionnaire Q1-Q5.",
    )
    p.add_argument("--db", type=Path, required=True, help="session database (created if absent)")
    how = p.add_mutually_exclusive_group(required=True)
    how.add_argument("--participant", help="participant id (e.g. P01): ask Q1-Q5 on stdin")
    how.add_argument(
        "--import",
        dest="import_csv",
        type=Path,
        metavar="FILE.csv",
        help="import a CSV with columns participant,q1,q2,q3,q4,q5; all rows or none",
    )
    p.add_argument("--replace", action="store_true", help="overwrite answers already stored")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run `nod questionnaire`; returns the exit code (2 for bad input, 1 when aborted)."""
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    if args.import_csv is not None:
        try:
            with args.import_csv.open(newline="", encoding="utf-8-sig") as fh:
                records = read_csv(fh, str(args.import_csv))
        except OSError as exc:
            return fail(PROG, f"error: cannot read {args.import_csv}: {exc.strerror or exc}")
        except UnicodeDecodeError:
            return fail(PROG, f"error: {args.import_csv}: not UTF-8 text; save the CSV as UTF-8")
        except CsvError as exc:
            return fail(PROG, f"error: {exc}; nothing stored")
        source = f"csv:{args.import_csv.name}"
    else:
        try:
            participant = parse_participant(args.participant)
        except ValueError as exc:
            return fail(PROG, f"error: --participant: {exc}")
        try:  # a damaged store is refused before the participant answers, not after
            if args.db.is_file():
                Store(args.db).close()
        except (sqlite3.Error, OSError) as exc:
            return fail(PROG, f"error: cannot open {args.db}: {exc}")
        try:
            record = prompt_answers(participant, sys.stdin.readline, sys.stdout.write)
        except (InputEndedError, KeyboardInterrupt) as exc:
            why = str(exc) if isinstance(exc, InputEndedError) else "interrupted"
            print(f"{PROG}: aborted: {why}; nothing stored for {participant}", file=sys.stderr)
            return 1
        records = [record]
        source = "prompt"
    try:
        store = Store(args.db)
    except (sqlite3.Error, OSError) as exc:
        return fail(PROG, f"error: cannot open {args.db}: {exc}")
    try:
        known = {s["participant"] for s in store.sessions()}
        store.write_questionnaires(records, time.time_ns(), source, args.replace)
    except ValueError as exc:
        return fail(PROG, f"error: {exc}; nothing stored")
    finally:
        store.close()
    unknown = sorted(r.participant for r in records if r.participant not in known)
    if unknown:
        print(f"{PROG}: note: no session yet for {', '.join(unknown)}", file=sys.stderr)
    print(f"stored answers for {len(records)} participant(s) in {args.db}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
