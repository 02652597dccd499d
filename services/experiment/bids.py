"""`nod export --bids DIR`: a study's stores as a BIDS dataset (the beh and motion datatypes).

The layout (BIDS 1.11; checked by the official validator in tests/unit/test_bids_export.py):

    dataset_description.json  README.md  participants.tsv  participants.json
    sub-<id>/[ses-<n>/]beh/sub-<id>[_ses-<n>]_task-consensus_beh.tsv      one row per trial
                                                      …_beh.json, …_events.tsv, …_events.json
    sub-<id>/[ses-<n>/]motion/sub-<id>[_ses-<n>]_task-consensus_tracksys-<camera|simulated>_
                                                      motion.tsv, motion.json, channels.tsv
                                                      channels.json
    sub-<id>/sub-<id>_sessions.tsv (+ .json)          only when someone has several sessions

`<id>` is the stored participant id without its non-alphanumeric characters (two ids that
become one are refused); `ses-<n>` is their n-th session, and the level is left out when
everyone has one. One clock per session: every onset and the motion's latency are seconds from
the session's start (`sessions.started_ns`, the conductor's rig clock, which the camera's
capture times and the speaker's played times share). No wall-clock date is written.
Simulated sessions (`StoredSession.simulated`) say so in participants.tsv, in every sidecar's
notes, in the tracking system's name and label, and in the README. Participants who withdrew
are left out as by every reader (`services.store.withdrawals`).
"""

from __future__ import annotations

import json
import re
import sqlite3
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from services.core.node import package_version
from services.experiment.bids_events import Event, StoredSession, session_events
from services.experiment.bids_sidecars import (
    CHANNEL_TYPES,
    CHANNELS,
    INSTRUCTIONS,
    TASK,
    TASK_DESCRIPTION,
    beh_sidecar,
    channels_sidecar,
    events_sidecar,
    participants_sidecar,
    policy_columns,
    sessions_sidecar,
)
from services.model.geometry import COLOURS
from services.store import records as rec
from services.store import session_rows
from services.store.estimates import read_estimates
from services.store.policies import read_policies
from services.store.provenance import read_provenance
from services.store.withdrawals import WithdrawnFilter

BIDS_VERSION = "1.11.1"
NAME = "Human-robot consensus with robotic eye gaze (nod-hri)"
NA = "n/a"


@dataclass(frozen=True, slots=True)
class Written:
    """What `export_bids` wrote."""

    participants: int
    sessions: int
    simulated: int  # of the sessions
    files: int


def read_sessions(db: sqlite3.Connection, keep: WithdrawnFilter) -> list[StoredSession]:
    """Every session of the store(s) whose participant `keep` keeps, oldest first."""
    options = {s: tuple(json.loads(n)) for s, n in db.execute(
        "SELECT session, names FROM option_sets")}
    orders = {s: tuple(json.loads(o)) for s, o in db.execute(
        "SELECT session, options FROM session_orders")}
    rows = db.execute(
        "SELECT session, participant, rig, seed, started_ns, finished_ns, status, config "
        "FROM sessions ORDER BY started_ns, session"
    ).fetchall()
    policies, estimates = read_policies(db), read_estimates(db)
    out = []
    for session, participant, rig, seed, started, finished, status, config in rows:
        if not keep.keeps(str(participant)):
            continue
        out.append(StoredSession(
            session=str(session), participant=str(participant), rig=str(rig), seed=seed,
            started_ns=int(started), finished_ns=finished, status=str(status),
            # a session stored before option sets were ran the paper's red and blue
            config=_json_object(config), options=options.get(session, COLOURS),
            order=orders.get(session), trials=tuple(session_rows.trials(db, session)),
            samples=tuple((int(r[0]), rec.Sample(r[1], bool(r[2]), *r[3:])) for r in db.execute(
                "SELECT trial, t_ns, detected, hand_x, hand_y, z_h, z_r, b_r, ee_x, ee_y, "
                "theta, distance, landmarks FROM samples WHERE session = ? ORDER BY t_ns",
                (session,))),
            cues=tuple(rec.CueRecord(*r) for r in db.execute(
                "SELECT trial, attempt, cue, planned_ns, played_ns FROM cues WHERE session = ? "
                "ORDER BY planned_ns", (session,))),
            safety=tuple(session_rows.safety_events(db, session)),
            interruptions=tuple(session_rows.interruptions(db, session)),
            rig_events=tuple(session_rows.rig_events(db, session)),
            policy=policies.get(session), estimates=tuple(estimates.get(session, ())),
        ))
    return out


def _json_object(text: str) -> dict[str, Any]:
    try:
        value = json.loads(text)
    except ValueError:
        return {}
    return value if isinstance(value, dict) else {}


def consent_versions(db: sqlite3.Connection) -> dict[str, str]:
    """Each participant's consent form version, where the store keeps one (else absent).

    Read from a session's provenance (its study file's `consent_version`, the latest run's),
    in a store that keeps provenance; an older store has none.
    """
    if "consent_version" not in _columns(db, "provenance"):
        return {}
    rows = db.execute(
        "SELECT s.participant, p.consent_version FROM provenance p JOIN sessions s "
        "ON s.session = p.session WHERE p.consent_version IS NOT NULL ORDER BY p.started_ns"
    )
    return {str(pid): str(v) for pid, v in rows}


# What a sidecar carries of each run's provenance: the code, the inputs' digests and the study's
# facts; not the files' paths, the hosts or the wall-clock times (no date is exported).
PROVENANCE_FIELDS = (
    "version", "sources_sha256", "params_hash", "params_sha256", "rig_sha256", "policy_sha256",
    "study_name", "study_sha256", "consent_version", "allocation_seed", "preregistration",
    "recording_sha256",
)


def session_provenance(db: sqlite3.Connection) -> dict[str, list[dict[str, Any]]]:
    """Each session's runs (oldest first) as its sidecars' `Provenance`; {} in an older store."""
    if "sources_sha256" not in _columns(db, "provenance"):
        return {}
    out: dict[str, list[dict[str, Any]]] = {}
    for run in read_provenance(db):
        row = run.provenance.as_dict()
        out.setdefault(run.session, []).append(
            {k: row[k] for k in PROVENANCE_FIELDS if row[k] is not None})
    return out


def _columns(db: sqlite3.Connection, table: str) -> list[str]:
    """A table's (or view's) columns; [] when there is none."""
    try:
        return [c[0] for c in db.execute(f'SELECT * FROM "{table}" LIMIT 0').description]
    except sqlite3.OperationalError:
        return []


def subject_labels(participants: Iterable[str]) -> dict[str, str]:
    """Each participant id's BIDS label (its letters and digits); ValueError if two collide."""
    out: dict[str, str] = {}
    seen: dict[str, str] = {}
    for pid in participants:
        label = re.sub(r"[^A-Za-z0-9]", "", pid)
        if not label:
            raise ValueError(f"participant id {pid!r} has no letter or digit for a BIDS label")
        if label in seen and seen[label] != pid:
            raise ValueError(f"participant ids {seen[label]!r} and {pid!r} are both sub-{label} "
                             "in BIDS (letters and digits only): give one of them a new id")
        seen[label] = pid
        out[pid] = label
    return out


def order_of(s: StoredSession) -> tuple[str, ...]:
    """The option O of each consensus trial, as started (else as stored in its trials)."""
    if s.order is not None:
        return s.order
    return tuple(t.option for t in s.trials if t.mode == "consensus" and t.option is not None)


def tracking_system(s: StoredSession) -> tuple[str, str]:
    """The tracksys label and the tracking system's name of a session's hand."""
    if s.rig == "offline":
        return "simulated", "simulated participant of the offline closed loop (nod cohort)"
    if s.simulated:
        return "simulated", "simulated participant (nod sim) published as the camera would"
    return "camera", "overhead camera with a hand tracker (nod vision)"


def sampling(s: StoredSession) -> tuple[float | str, float | str, float]:
    """The samples' rate measured: (nominal: 1 / the median interval, effective, duration s).

    Intervals are taken within a trial (samples are kept from a trial's go to its end).
    """
    by_trial: dict[int, list[int]] = {}
    for trial, m in s.samples:
        by_trial.setdefault(trial, []).append(m.t_ns)
    gaps = [b - a for ts in by_trial.values() for a, b in zip(ts, ts[1:], strict=False) if b > a]
    span = (s.samples[-1][1].t_ns - s.samples[0][1].t_ns) / 1e9 if s.samples else 0.0
    if not gaps:
        return NA, NA, span
    nominal = round(1e9 / statistics.median(gaps), 2)
    return nominal, round(len(gaps) * 1e9 / sum(gaps), 4), span


def _seconds(t_ns: int | None, start_ns: int) -> str:
    return NA if t_ns is None else f"{(t_ns - start_ns) / 1e9:.6f}"


def _cell(value: Any) -> str:
    if value is None:
        return NA
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, float):
        return repr(value)
    return str(value)


def beh_rows(s: StoredSession) -> tuple[list[str], list[list[str]]]:
    """beh.tsv of a session: one row per stored trial."""
    header = ["trial", "mode", "option", "gaze_level", "gaze_yaw", "gaze_pitch", "go_onset",
              "end_onset", "human", "robot", "outcome", "switches", "violations", "clicks",
              "score", "end_reason", "interrupted", "attempts"]
    rows = [[_cell(t.trial), t.mode, _cell(t.option), t.gaze_level, _cell(t.yaw),
             _cell(t.pitch), _seconds(t.t_go_ns, s.started_ns),
             _seconds(t.t_end_ns, s.started_ns), _cell(t.human), _cell(t.robot),
             _cell(t.outcome), _cell(t.switches), _cell(t.violations), _cell(t.clicks),
             _cell(t.score), " ".join(t.end_reason.split()) or NA, _cell(t.interrupted),
             _cell(t.attempts)] for t in s.trials]
    if s.policy is not None:  # the settings the robot policy chose for each trial
        header += ["policy_b_star", "policy_u_r"]
        for t, row in zip(s.trials, rows, strict=True):
            chosen = s.policy.trials.get(t.trial)
            row += [NA, NA] if chosen is None else [_cell(chosen.b_star), _cell(chosen.u_r)]
    names = estimate_names(s)
    if names:  # the person as estimated after each trial (`nod estimate`)
        header += ["estimate_trials_seen"] + [f"estimate_{n}{part}" for n in names
                                              for part in ("", "_low", "_high")]
        after = {e.trial: e for e in s.estimates}
        for t, row in zip(s.trials, rows, strict=True):
            e = after.get(t.trial)
            by = {p.name: p for p in e.params} if e is not None else {}
            row.append(_cell(e.trials_seen) if e is not None else NA)
            for n in names:
                p = by.get(n)
                row += [NA] * 3 if p is None else [_cell(p.estimate), _cell(p.low),
                                                   _cell(p.high)]
    return header, rows


def estimate_names(s: StoredSession) -> list[str]:
    """The parameters estimated in a session, in the estimator's order."""
    names: list[str] = []
    for e in s.estimates:
        names += [p.name for p in e.params if p.name not in names]
    return names


def event_rows(s: StoredSession, events: Sequence[Event]) -> tuple[list[str], list[list[str]]]:
    """events.tsv of a session."""
    header = ["onset", "duration", "trial_type", "trial", "attempt", "value", "planned_onset",
              "source"]
    rows = [[_seconds(e.t_ns, s.started_ns), f"{e.duration_ns / 1e9:.6f}", e.trial_type,
             _cell(e.trial), _cell(e.attempt), e.value, _seconds(e.planned_ns, s.started_ns),
             e.source] for e in events]
    return header, rows


def motion_rows(s: StoredSession) -> list[list[str]]:
    """motion.tsv of a session: one row per stored sample, one column per `CHANNELS` entry."""
    return [[_seconds(m.t_ns, s.started_ns), _cell(trial), _cell(m.detected), _cell(m.hand_x),
             _cell(m.hand_y), _cell(m.ee_x), _cell(m.ee_y), _cell(m.z_h), _cell(m.z_r),
             _cell(m.b_r), _cell(m.theta), _cell(m.distance)] for trial, m in s.samples]


def note_of(s: StoredSession) -> str:
    """The line each sidecar of a session carries: which session, simulated or not."""
    who = ("SIMULATED participant: not a person's data" if s.simulated
           else "a person on the rig")
    return (f"{who}; nod session {s.session} on rig {s.rig}, status {s.status}. Times: seconds "
            "from the session's start (one rig clock).")


def motion_sidecar(s: StoredSession, label: str, system: str) -> dict[str, Any]:
    """motion.json of a session: the tracking system, its measured rate, its channels."""
    nominal, effective, span = sampling(s)
    count = {t: sum(c.type == t for c in CHANNELS) for t in CHANNEL_TYPES}
    simulated = label == "simulated"
    return {
        "TaskName": TASK,
        "TaskDescription": TASK_DESCRIPTION,
        "Instructions": INSTRUCTIONS,
        "TrackingSystemName": system,
        # A simulated participant is software: no make, model or serial number to name.
        **({"Manufacturer": "n/a (simulated)", "ManufacturersModelName": "n/a (simulated)",
            "DeviceSerialNumber": "n/a (simulated)"} if simulated else {}),
        "SoftwareVersions": f"nod-hri {package_version()}",
        "SamplingFrequency": nominal,
        "SamplingFrequencyEffective": effective,
        "RecordingDuration": round(span, 6),
        "MotionChannelCount": len(CHANNELS),
        **{f"{t}ChannelCount": count[t] for t in CHANNEL_TYPES},
        "TrackedPointsCount": 2,
        "SpatialAxes": "RB_",
        "MissingValues": NA,
        "SubjectArtefactDescription": NA,
        "Notes": note_of(s) + " Samples are kept from each trial's go to its end (none between "
        "trials), decimated to at most 60 Hz: the latency channel gives each sample's time. "
        "SamplingFrequency is 1 / the median interval within trials; "
        "SamplingFrequencyEffective their mean rate.",
    }


def write_tsv(path: Path, header: Sequence[str] | None, rows: Iterable[Sequence[str]]) -> None:
    """A TSV file (UTF-8, LF, no quoting); `header` None: none (motion.tsv has no header row).

    A tab or line break inside a field would shift every column after it: each becomes a space.
    """
    with path.open("w", encoding="utf-8", newline="\n") as fh:
        for row in ([header] if header is not None else []):
            fh.write(_line(row))
        for row in rows:
            fh.write(_line(row))


def _line(fields: Sequence[str]) -> str:
    return "\t".join(re.sub(r"[\t\r\n]", " ", f) for f in fields) + "\n"


def write_json(path: Path, data: dict[str, Any]) -> None:
    """A JSON sidecar, indented, UTF-8."""
    path.write_text(json.dumps(data, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")


def export_bids(
    db: sqlite3.Connection, out: Path, keep: WithdrawnFilter, sources: Sequence[str] = ()
) -> Written:
    """Write the store(s) on `db` (`union_of`) as a BIDS dataset in `out`."""
    sessions = read_sessions(db, keep)
    labels = subject_labels(dict.fromkeys(s.participant for s in sessions))
    by_person: dict[str, list[StoredSession]] = {}
    for s in sessions:
        by_person.setdefault(s.participant, []).append(s)
    several = any(len(v) > 1 for v in by_person.values())
    out.mkdir(parents=True, exist_ok=True)
    provenance = session_provenance(db)
    files = 0
    for pid, own in by_person.items():
        sub = f"sub-{labels[pid]}"
        for n, s in enumerate(own, start=1):
            ses = f"ses-{n}" if several else None
            files += _write_session(s, out / sub / (ses or ""), "_".join(filter(None, (sub, ses))),
                                    provenance.get(s.session, []))
        if several:
            write_tsv(out / sub / f"{sub}_sessions.tsv",
                      ["session_id", "status", "simulated", "order"],
                      [[f"ses-{n}", s.status, str(s.simulated).lower(), " ".join(order_of(s))
                        or NA] for n, s in enumerate(own, start=1)])
            write_json(out / sub / f"{sub}_sessions.json", sessions_sidecar())
            files += 2
    consent = consent_versions(db)
    write_tsv(out / "participants.tsv", list(participants_sidecar()), [
        [f"sub-{labels[pid]}", str(len(own)), own[-1].status,
         str(any(s.simulated for s in own)).lower(), own[0].rig,
         " ".join(order_of(own[0])) or NA, consent.get(pid, NA)]
        for pid, own in by_person.items()
    ])
    write_json(out / "participants.json", participants_sidecar())
    simulated = sum(s.simulated for s in sessions)
    runs = [run for s in sessions for run in provenance.get(s.session, [])]
    write_json(out / "dataset_description.json", dataset_description(
        len(sessions), simulated, sources, runs))
    (out / "README.md").write_text(readme(len(by_person), len(sessions), simulated),
                                   encoding="utf-8")
    return Written(len(by_person), len(sessions), simulated, files + 4)


def _write_session(s: StoredSession, where: Path, prefix: str,
                   runs: list[dict[str, Any]]) -> int:
    """One session's beh and motion files (its provenance `runs` in the sidecars); how many."""
    carried = {"Provenance": runs} if runs else {}
    beh = where / "beh"
    beh.mkdir(parents=True, exist_ok=True)
    stem = f"{prefix}_task-{TASK}"
    write_tsv(beh / f"{stem}_beh.tsv", *beh_rows(s))
    write_json(beh / f"{stem}_beh.json", {**beh_sidecar(
        list(s.options), [t.gaze_level for t in s.trials], note_of(s)),
        **policy_columns(s.policy is not None, estimate_names(s)), **carried})
    events = event_rows(s, session_events(s))
    write_tsv(beh / f"{stem}_events.tsv", *events)
    write_json(beh / f"{stem}_events.json", events_sidecar(note_of(s), package_version()))
    if not s.samples:
        return 4
    label, system = tracking_system(s)
    motion = where / "motion"
    motion.mkdir(parents=True, exist_ok=True)
    mstem = f"{stem}_tracksys-{label}"
    # The same events beside the motion (BIDS pairs each recording with its events file).
    write_tsv(motion / f"{mstem}_events.tsv", *events)
    write_json(motion / f"{mstem}_events.json", events_sidecar(note_of(s), package_version()))
    write_tsv(motion / f"{mstem}_motion.tsv", None, motion_rows(s))
    write_json(motion / f"{mstem}_motion.json", {**motion_sidecar(s, label, system), **carried})
    write_tsv(motion / f"{mstem}_channels.tsv",
              ["name", "component", "type", "tracked_point", "units", "reference_frame",
               "description"],
              [[c.name, c.component, c.type, c.tracked_point, c.units, c.frame, c.description]
               for c in CHANNELS])
    write_json(motion / f"{mstem}_channels.json", channels_sidecar())
    return 10


def dataset_description(sessions: int, simulated: int, sources: Sequence[str],
                        runs: Sequence[dict[str, Any]] = ()) -> dict[str, Any]:
    """dataset_description.json: the dataset, the software that wrote and ran it, what is simulated.

    GeneratedBy names the exporter, then each code version and sources digest that ran sessions
    (from their provenance `runs`).
    """
    code: dict[tuple[str, str], int] = {}
    for run in runs:
        ident = (str(run["version"]), str(run["sources_sha256"]))
        code[ident] = code.get(ident, 0) + 1
    kind = ("every session SIMULATED" if simulated == sessions
            else f"{simulated} of {sessions} sessions SIMULATED" if simulated
            else "no session simulated")
    return {
        "Name": NAME,
        "BIDSVersion": BIDS_VERSION,
        "DatasetType": "raw",
        "GeneratedBy": [{
            "Name": "nod-hri",
            "Version": package_version(),
            "Description": f"nod export --bids of {len(sources) or 1} session store(s); {kind} "
            "(participants.tsv: simulated)",
        }, *({
            "Name": "nod-hri",
            "Version": version,
            "Description": f"ran {n} session run(s) of this dataset (their sidecars' "
            f"Provenance); services sources sha256 {digest}",
        } for (version, digest), n in sorted(code.items()))],
    }


def readme(participants: int, sessions: int, simulated: int) -> str:
    """README.md of the dataset: what it holds, its clock, what is simulated, what is not in it."""
    return (
        f"# {NAME}\n\n{TASK_DESCRIPTION}\n\n"
        f"{participants} participant(s), {sessions} session(s); {simulated} session(s) of a "
        "SIMULATED participant (participants.tsv `simulated`, each sidecar's `Notes`, the "
        "motion files' `tracksys-simulated`).\n\n"
        "Per session: `beh/*_beh.tsv` one row per trial, `beh/*_events.tsv` the cues, presses, "
        "trial ends, interruptions, safety and rig events, `motion/*_motion.tsv` the hand "
        "centre, the arm's end effector and the robot's opinion variables per sample. Every "
        "time is seconds from the session's start on the rig's one clock; no date is "
        "included. Not included: video (the camera's frames are never stored), names and "
        "demographics.\n\nWritten by `nod export --bids` (nod-hri).\n"
    )
