"""`nod study start --sim`: the next participant's real session — a router, every service its own
process — runs their counterbalanced order (and, in the paper's study, their robot-policy
condition), and the store keeps the order (and the policy) with the session."""

import json
import sqlite3

import pytest

from services.model.gaze import gaze_toward
from services.model.params import NodConfig
from services.study.studyfile import load
from tests.processes import run_nod

from .conftest import SHORT, SHORT_THREE, free_port

pytestmark = pytest.mark.integration

# option count: (the protocol: 1 control trial, 2 consensus trials; its options; one full block
# of the Latin square: the rotations of its O order under each cyclic relabelling of the options)
STUDIES = {
    2: (SHORT, ("red", "blue"), ["BR", "BR", "RB", "RB"]),
    3: (SHORT_THREE, ("red", "blue", "green"), ["BG", "BR", "GB", "GR", "RB", "RG"]),
}


@pytest.mark.parametrize("n", sorted(STUDIES), ids=lambda n: f"{n} options")
def test_study_start_runs_the_next_participant_with_their_order(tmp_path, n):
    protocol, names, block = STUDIES[n]
    params, study, db = tmp_path / "short.toml", tmp_path / "study.toml", tmp_path / "s.sqlite"
    params.write_text(protocol)
    policies = ["--policies", "paper"] if n == 2 else []  # a robot-policy condition (issue 36)
    init = run_nod("study", "init", str(study), "--participants", str(len(block)), "--seed",
                   "5", "--params", str(params), *policies, timeout=60)
    assert init.returncode == 0, init.stderr
    assert load(study).options == names  # the params' option set is the study's
    roster = load(study).participants
    assert sorted(e.letters for e in roster) == block  # one full block
    listen = f"tcp/127.0.0.1:{free_port()}"
    sim = ["--", "--speed", "8", "--stale-ms", "2000", "--listen", listen]

    for entry in roster[:2]:  # the first two slots, each as `nod study start` picks the next
        consent = run_nod("study", "consent", str(study), "--db", str(db), "--participant",
                          entry.id, "--yes", "--age", "25-34", timeout=60)
        assert consent.returncode == 0, consent.stderr
        nxt = run_nod("study", "next", str(study), "--db", str(db), timeout=60)
        assert nxt.stdout.startswith(f"{entry.id} (slot {entry.slot} of {len(block)})"), nxt.stdout
        run = run_nod("study", "start", str(study), "--db", str(db), "--sim", *sim, timeout=400)
        assert run.returncode == 0, run.stdout + run.stderr
        order = entry.letters if n == 2 else ",".join(entry.order)  # by names over N options
        assert f"--participant {entry.id} --order {order}" in run.stdout
        assert ("--options" in run.stdout) == (n > 2)  # the session's table of N boxes
        assert ("--policy paper" in run.stdout) == (n == 2)  # the participant's condition
        assert "3 trials of 1 participant(s) stored" in run.stdout

    con = sqlite3.connect(db)
    sessions = con.execute(
        "SELECT s.participant, s.seed, s.status, o.options, o.again FROM sessions s "
        "JOIN session_orders o ON o.session = s.session ORDER BY s.started_ns"
    ).fetchall()
    assert sessions == [
        (e.id, e.slot, "complete", json.dumps(list(e.order)), None) for e in roster[:2]
    ]
    ran = con.execute("SELECT s.participant, p.policy FROM policy_sessions p JOIN sessions s "
                      "ON s.session = p.session ORDER BY s.started_ns").fetchall()
    assert ran == ([(e.id, "paper") for e in roster[:2]] if n == 2 else [])  # stored with it
    for entry in roster[:2]:
        trials = con.execute(
            "SELECT t.mode, t.option, t.yaw FROM trials t JOIN sessions s ON s.session = "
            "t.session WHERE s.participant = ? ORDER BY t.trial", (entry.id,)
        ).fetchall()
        assert [m for m, _, _ in trials] == ["dissensus", "consensus", "consensus"]
        assert tuple(o for _, o, _ in trials[1:]) == entry.order  # the roster's O, as run
        table = NodConfig().table(n)  # the gaze toward O, at each trial's level (low, significant)
        assert [yaw for _, _, yaw in trials[1:]] == pytest.approx(
            [gaze_toward(table, names.index(o), level).yaw
             for o, level in zip(entry.order, ("low", "significant"), strict=True)], abs=1e-9)
        stored = json.loads(con.execute("SELECT config FROM sessions WHERE participant = ?",
                                        (entry.id,)).fetchone()[0])
        ran = ([t["option"] for t in stored["protocol"]["trials"][1:]] if n == 2 else
               [names[t["option"]] for t in stored["option_schedule"][1:]])
        assert ran == list(entry.order)

    status = run_nod("study", "status", str(study), "--db", str(db), "--json", timeout=60)
    doc = json.loads(status.stdout)
    assert [p["status"] for p in doc["participants"]] == ["done"] * 2 + ["left"] * (len(block) - 2)
    assert doc["next"] == roster[2].id
    assert doc["participants"][0]["demographics"] == {"age": "25-34"}
    assert doc.get("conditions") == ({"paper": "paper"} if n == 2 else None)

    again = run_nod("study", "start", str(study), "--db", str(db), "--sim", "--participant",
                    roster[0].id, *sim, timeout=60)
    assert again.returncode == 2
    assert again.stderr.count("\n") == 1 and "already has a complete session" in again.stderr


def test_nod_run_twice_into_one_database_takes_the_next_free_id(tmp_path):
    params, db = tmp_path / "short.toml", tmp_path / "s.sqlite"
    params.write_text(SHORT)
    for _ in range(2):  # no --participant: P01, then P02 (P01 is done and never reused)
        run = run_nod("run", "--sim", "--speed", "8", "--stale-ms", "2000", "--params",
                      str(params), "--db", str(db), "--listen",
                      f"tcp/127.0.0.1:{free_port()}", timeout=400)
        assert run.returncode == 0, run.stdout + run.stderr
    con = sqlite3.connect(db)
    rows = con.execute("SELECT s.participant, o.options FROM sessions s JOIN session_orders o "
                       "ON o.session = s.session ORDER BY s.started_ns").fetchall()
    assert rows == [("P01", '["red", "blue"]'), ("P02", '["red", "blue"]')]  # the schedule's own
