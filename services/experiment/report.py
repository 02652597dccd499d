"""`nod report`: the per-trial results of a session, from its SQLite file, and its provenance.

`--json` prints one object: the session, its trials (one object each) and its provenance (one
object per conductor run, `services.store.provenance`; [] for a session stored without it).
"""

from __future__ import annotations

import argparse
import json
from datetime import datetime
from pathlib import Path
from typing import Any

from services.core.cli import Parser, fail
from services.store import Store, StoreError
from services.store.provenance import SessionProvenance, read_provenance

SHORT = 12  # hex digits of a SHA-256 shown in the table (--json has all 64)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod report`."""
    p = Parser(prog="nod report", description="Per-trial results of a session.")
    p.add_argument("--db", type=Path, required=True, help="session store written by nod run")
    p.add_argument("--session", default=None, help="session id (default: the latest session)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    return p


def main(argv: list[str] | None = None) -> int:
    """Print one session's trials."""
    args = build_parser().parse_args(argv)
    try:
        store = Store.existing(args.db)  # a damaged store is refused here, untouched
    except StoreError as exc:
        return fail("nod report", exc)
    try:
        trials = store.trials(args.session)
        session = trials[0][0] if trials else None
        events = store.safety_events(session) if session else []
        broken = store.interruptions(session) if session else []
        runs = read_provenance(store, [session]) if session else []
    finally:
        store.close()
    if args.session is not None and not trials:
        return fail("nod report", f"no trials for session {args.session!r}")
    rows: list[dict[str, Any]] = [  # JSON objects, one per trial (--json prints them)
        {
            "session": session,
            "trial": t.trial,
            "mode": t.mode,
            "option": t.option,
            "robot": t.robot,
            "human": t.human,
            "outcome": t.outcome,
            "switches": t.switches,
            "violations": t.violations,
            "score": t.score,
            "interrupted": t.interrupted,
            "attempts": t.attempts,
            "safe_stops": sum(e.trial == t.trial and e.event == "safe_stop" for e in events),
            "estops": sum(e.trial == t.trial and e.event == "estop" for e in events),
            "end_reason": t.end_reason,
        }
        for session, t in trials
    ]
    if args.json:
        doc = {"session": session, "trials": rows, "provenance": [r.as_dict() for r in runs]}
        print(json.dumps(doc, indent=2))
        return 0
    for r in rows:
        flags = " INTERRUPTED (not scored)" if r["interrupted"] else ""
        safety = f" safe_stops={r['safe_stops']} estops={r['estops']}" if r["safe_stops"] else ""
        retries = f" attempts={r['attempts']}" if r["attempts"] > 1 else ""
        print(
            f"{r['trial']:>3} {r['mode']:<10} {r['option'] or '-':<5} robot={r['robot'] or '-':<5}"
            f" human={r['human'] or '-':<5} {r['outcome'] or '-':<3} switches={r['switches']}"
            f" violations={r['violations']} score={r['score']}{retries}{safety}{flags}"
        )
    for b in broken:
        print(f"    trial {b.trial} attempt {b.attempt} interrupted: {b.reason}")
    if session is not None:
        for line in provenance_lines(runs):
            print(line)
    return 0


def _file(path: str | None, digest: str | None) -> str:
    return f"{path} (sha256 {(digest or '?')[:SHORT]})"


def provenance_lines(runs: list[SessionProvenance]) -> list[str]:
    """The provenance of each run of a session, a few lines each (one when none was kept)."""
    if not runs:
        return ["provenance: not recorded (stored before provenance was kept, or not by "
                "nod experiment)"]
    lines = []
    for run in runs:
        p = run.provenance
        when = datetime.fromtimestamp(run.started_ns / 1e9).isoformat(timespec="seconds")
        lines.append(f"provenance of the run started {when}:")
        lines.append(f"    code       nod-hri {p.version}, sources sha256 "
                     f"{p.sources_sha256[:SHORT]}")
        params = "SPEC defaults" if p.params_file is None else _file(p.params_file,
                                                                     p.params_sha256)
        lines.append(f"    params     hash {p.params_hash}: {params}")
        for name, path, digest in (("rig file", p.rig_file, p.rig_sha256),
                                   ("policy", p.policy_file, p.policy_sha256)):
            if path is not None:
                lines.append(f"    {name:<10} {_file(path, digest)}")
        if p.study_file is not None:
            lines.append(
                f"    study      {p.study_name}: {_file(p.study_file, p.study_sha256)}; consent "
                f"{p.consent_version or 'version not given'}; allocation seed "
                f"{'not given' if p.allocation_seed is None else p.allocation_seed}; "
                f"pre-registration {p.preregistration or 'not given'}")
        hosts = "; ".join(f"{s} on {', '.join(h)}" for s, h in p.hosts.items())
        lines.append(f"    hosts      {hosts or 'not recorded (the run did not end cleanly)'}")
        if p.recording_file is not None:
            lines.append(f"    recording  {_file(p.recording_file, p.recording_sha256)}")
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
