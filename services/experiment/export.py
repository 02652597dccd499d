"""`nod export`: a session database as CSV files that pandas and R read directly.

Writes sessions.csv, trials.csv, samples.csv, questionnaires.csv, safety_events.csv,
rig_events.csv, interruptions.csv, cues.csv (the countdown words and go as `nod speaker`
played them: planned and played onset, rig-clock ns), fits.csv (`nod fit`'s per-participant
estimates and 90 % intervals, identifiable parameters only), provenance.csv (one row per
conductor run of a session: code version and sources digest, params hash and the files'
SHA-256, study, consent version, allocation seed, pre-registration, hosts as JSON, the
recording and its SHA-256; `services.core.provenance`), policies.csv (the robot policy's
b*, gaze level and u_r per trial, with the policy's name and SHA-256: docs/adaptive.md),
estimates.csv (the participant's parameters estimated after each trial by `nod estimate`:
estimate, 90 % interval, a 0/1 parameter's probability), withdrawn_aggregates.csv (the anonymous
per-trial outcome counts of participants withdrawn with `aggregate`) and participants.csv (each
participant's consent record — every column of `participants`,
demographics as JSON — and their withdrawal, if any: `withdrawn_ns`, `withdrawal_reason`,
`withdrawal_deleted`, `deleted_ns`) into one directory, each with a header
row of the database's column names (the per-session tables gain a `participant` column after
`session` for convenience). A trial with `interrupted` = 1 was broken by a safe stop or an
e-stop and never scored. A participant who withdrew (`services.store.withdrawals`) is in
none of the files, and one printed line names them, unless `--include-withdrawn`.
Conventions, chosen so that `pandas.read_csv(path)` and R's
`read.csv(path)` need no options:

- UTF-8, comma separated, LF line ends, fields quoted only when needed (the sessions'
  `config` column is JSON text and gets quoted);
- a sample's `landmarks` (the tracker's points) is one field "x1 y1 x2 y2 …" (space
  separated, float32 precision);
- a missing value (SQL NULL: a timeout's outcome, an undetected hand) is written `NA`, which
  both read as missing in numeric and text columns alike (an empty field would come back as
  the empty string in R's text columns);
- floats are written with Python's shortest round-trip repr, so no precision is lost (a
  non-finite float, which the store should never hold, is NaN / Inf / -Inf);
- `detected` is 0/1; times are integer nanoseconds (`*_ns`).
"""

from __future__ import annotations

import argparse
import csv
import math
import sqlite3
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from services.core.cli import Parser, fail
from services.experiment.bids import Written, export_bids
from services.store import StoreError
from services.store.provenance import FIELDS as PROVENANCE_FIELDS
from services.store.records import unpack_landmarks
from services.store.study_stores import open_stores, union_of
from services.store.withdrawals import WithdrawnFilter, withdrawn_filter

PROG = "nod export"
MISSING = "NA"  # how a SQL NULL is written

QUERIES: dict[str, str] = {
    # `control_labels`: the rule that labelled the session's control trials (SPEC §6); a session
    # stored before the rule existed was labelled by switches.
    # `options`: the session's option set as a JSON list of names (the paper's: red, blue); a
    # trial's option, human and robot in trials.csv are names of it, whatever the number.
    "sessions": "SELECT s.*, COALESCE(json_extract(s.config, '$.protocol.control_labels'), "
    "'switches') AS control_labels, COALESCE(o.names, '[\"red\", \"blue\"]') AS options "
    "FROM sessions s LEFT JOIN option_sets o ON o.session = s.session "
    "ORDER BY s.started_ns, s.session",
    "trials": (
        "SELECT t.session, s.participant, t.trial, t.mode, t.option, t.gaze_level, t.yaw, "
        "t.pitch, t.t_go_ns, t.t_end_ns, t.human, t.robot, t.outcome, t.switches, "
        "t.violations, t.clicks, t.score, t.end_reason, t.interrupted, t.attempts FROM trials t "
        "LEFT JOIN sessions s ON s.session = t.session ORDER BY s.started_ns, t.session, t.trial"
    ),
    "samples": (
        "SELECT m.session, s.participant, m.trial, m.t_ns, m.detected, m.hand_x, m.hand_y, "
        "m.z_h, m.z_r, m.b_r, m.ee_x, m.ee_y, m.theta, m.distance, m.landmarks FROM samples m "
        "LEFT JOIN sessions s ON s.session = m.session "
        "ORDER BY s.started_ns, m.session, m.trial, m.t_ns"
    ),
    "questionnaires": "SELECT * FROM questionnaires ORDER BY participant",
    "safety_events": (
        "SELECT e.session, s.participant, e.trial, e.attempt, e.t_ns, e.device, e.event, "
        "e.reason FROM safety_events e LEFT JOIN sessions s ON s.session = e.session "
        "ORDER BY s.started_ns, e.session, e.t_ns"
    ),
    "rig_events": (
        "SELECT e.session, s.participant, e.trial, e.attempt, e.t_ns, e.host, e.service, e.kind, "
        "e.code, e.text FROM rig_events e LEFT JOIN sessions s ON s.session = e.session "
        "ORDER BY s.started_ns, e.session, e.t_ns"
    ),
    "interruptions": (
        "SELECT i.session, s.participant, i.trial, i.attempt, i.t_start_ns, i.t_ns, i.reason "
        "FROM interruptions i LEFT JOIN sessions s ON s.session = i.session "
        "ORDER BY s.started_ns, i.session, i.trial, i.attempt"
    ),
    "cues": (
        "SELECT c.session, s.participant, c.trial, c.attempt, c.cue, c.planned_ns, c.played_ns "
        "FROM cues c LEFT JOIN sessions s ON s.session = c.session "
        "ORDER BY s.started_ns, c.session, c.trial, c.attempt, c.planned_ns"
    ),
    "fits": "SELECT * FROM fits ORDER BY participant, parameter",
    "provenance": (
        "SELECT p.session, s.participant, p.started_ns, p.finished_ns, "
        + ", ".join(f"p.{f}" for f in PROVENANCE_FIELDS) + " FROM provenance p "
        "LEFT JOIN sessions s ON s.session = p.session "
        "ORDER BY s.started_ns, p.session, p.started_ns"
    ),
    "withdrawn_aggregates": (
        "SELECT * FROM withdrawn_aggregates ORDER BY options, trial, mode, outcome"
    ),
    # The robot policy's settings per trial, with the policy (its name and file's SHA-256) and,
    # for a simulated participant, the kind of person the simulator drew.
    "policies": (
        "SELECT t.session, s.participant, p.policy, p.policy_sha256, p.kind, t.trial, t.b_star, "
        "t.gaze_level, t.u_r FROM policy_trials t LEFT JOIN policy_sessions p ON p.session = "
        "t.session LEFT JOIN sessions s ON s.session = t.session "
        "ORDER BY s.started_ns, t.session, t.trial"
    ),
    # The participant estimated after each trial (`nod estimate`): one row per parameter.
    "estimates": (
        "SELECT e.session, s.participant, e.trial, e.trials_seen, e.seconds, e.name, e.estimate, "
        "e.low, e.high, e.probability FROM person_estimates e LEFT JOIN sessions s ON "
        "s.session = e.session ORDER BY s.started_ns, e.session, e.trial, e.name"
    ),
}


def _field(value: Any) -> Any:
    """A SQLite value as a CSV field: NULL → NA, float → shortest round-trip text."""
    if value is None:
        return MISSING
    if isinstance(value, bytes):  # landmarks: "x1 y1 x2 y2 …" (float32 precision)
        return " ".join(f"{c:.7g}" for p in unpack_landmarks(value) for c in p)
    if isinstance(value, float):
        if math.isnan(value):
            return "NaN"
        if math.isinf(value):
            return "Inf" if value > 0 else "-Inf"
        return repr(value)
    return value


def write_rows(path: Path, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> int:
    """Write one CSV file with its header; return the number of data rows."""
    count = 0
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(header)
        for row in rows:
            writer.writerow([_field(v) for v in row])
            count += 1
    return count


def participants_query(db: sqlite3.Connection) -> str:
    """participants.csv: every consent record and every withdrawal, one row per participant.

    Every column of `participants` (one added later, a consent form's version, comes along),
    then the withdrawal's; a participant with a withdrawal but no consent row (deleted, or
    never recorded) has NA consent.
    """
    cols = [c[0] for c in db.execute("SELECT * FROM participants LIMIT 0").description]
    own = ", ".join(f'p."{c}"' for c in cols if c != "participant")
    return (
        f"SELECT ids.participant, {own}, w.withdrawn_ns, w.reason AS withdrawal_reason, "
        "w.deleted AS withdrawal_deleted, w.deleted_ns FROM (SELECT participant FROM "
        "participants UNION SELECT participant FROM withdrawals) ids "
        "LEFT JOIN participants p ON p.participant = ids.participant "
        "LEFT JOIN withdrawals w ON w.participant = ids.participant ORDER BY ids.participant"
    )


def export(
    db: sqlite3.Connection, out: Path, keep: WithdrawnFilter | None = None
) -> dict[str, int]:
    """Write every table of an open store as `<table>.csv` in `out`; rows written per table.

    The rows of withdrawn participants are left out (`keep`: the store's own filter when not
    given), found by the `participant` column or, in a table without one, by the session.
    """
    keep = keep if keep is not None else withdrawn_filter(db)
    out.mkdir(parents=True, exist_ok=True)
    owner = {str(s): str(p) for s, p in db.execute("SELECT session, participant FROM sessions")}
    counts: dict[str, int] = {}
    queries = {**QUERIES, "participants": participants_query(db)}
    for name, query in queries.items():
        cur = db.execute(query)
        header = [c[0] for c in cur.description]
        counts[name] = write_rows(out / f"{name}.csv", header, _kept(header, cur, keep, owner))
    return counts


def _kept(
    header: Sequence[str], rows: Iterable[Sequence[Any]], keep: WithdrawnFilter,
    owner: dict[str, str],
) -> Iterable[Sequence[Any]]:
    """The rows of the participants `keep` keeps (by `participant`, else by `session`).

    A table with neither (the anonymous aggregates) is nobody's: kept whole.
    """
    if keep.include or not keep.withdrawn or not {"participant", "session"} & set(header):
        return rows
    if "participant" in header:
        at = header.index("participant")
        return (r for r in rows if keep.keeps(str(r[at])))
    at = header.index("session")
    return (r for r in rows if keep.keeps(owner.get(str(r[at]), "")))


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod export`."""
    p = Parser(
        prog=PROG,
        description="Write a session database as CSV: sessions.csv, trials.csv, samples.csv, "
        "questionnaires.csv (headers; NA = missing; pandas.read_csv / R read.csv), and/or as "
        "a BIDS dataset (--bids).",
    )
    p.add_argument("--db", type=Path, required=True, action="append",
                   help="session database written by nod run; repeat it for one study of several "
                   "rigs' stores (their rows as one; a participant in two is refused)")
    p.add_argument("--out", type=Path, default=None, metavar="DIR", help="directory for CSVs")
    p.add_argument("--bids", type=Path, default=None, metavar="DIR",
                   help="write a BIDS dataset (beh and motion) into DIR (docs/data.md)")
    p.add_argument("--include-withdrawn", action="store_true",
                   help="export participants who withdrew too (default: left out, and named "
                   "in one line)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run `nod export`; returns the exit code (2 for bad input)."""
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    if args.out is None and args.bids is None:
        return fail(PROG, "error: say where: --out DIR (CSV files), --bids DIR (a BIDS dataset) "
                    "or both")
    counts: dict[str, int] = {}
    written: Written | None = None
    where = args.out
    try:
        with open_stores(args.db) as stores, union_of(stores) as db:
            keep = withdrawn_filter(db, args.include_withdrawn)
            if args.out is not None:
                counts = export(db, args.out, keep)
            where = args.bids
            if args.bids is not None:
                written = export_bids(db, args.bids, keep, [str(p) for p in args.db])
    except ValueError as exc:
        return fail(PROG, f"error: {exc}")
    except (sqlite3.Error, StoreError) as exc:
        return fail(PROG, f"error: cannot open {', '.join(map(str, args.db))}: {exc}")
    except OSError as exc:
        return fail(PROG, f"error: cannot write to {where}: {exc}")
    for name, n in counts.items():
        print(f"{args.out / (name + '.csv')}: {n} rows")
    if written is not None:
        print(f"{args.bids}: BIDS dataset of {written.participants} participant(s), "
              f"{written.sessions} session(s) ({written.simulated} simulated), "
              f"{written.files} files")
    if note := keep.note():
        print(f"{PROG}: {note}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
