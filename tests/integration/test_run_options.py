"""`nod run --sim --options 3`: a table of three boxes, every service its own process."""

from __future__ import annotations

import csv
import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from services.actuation.calibrate import config_toml
from services.actuation.feetech_arm import FeetechArmConfig
from services.store import Store
from tests.emulators.feetech_emulator import IDS, POSES_BY_N
from tests.processes import run_nod

from .conftest import (
    ROOT,
    SHORT_THREE,
    assert_estop_broke_trial_2_and_every_break_was_repeated,
    free_port,
    last_session_record,
    wait_for,
)

pytestmark = pytest.mark.integration
NAMES = ("red", "blue", "green")


def _short(tmp_path: Path) -> str:
    """SHORT_THREE's params file: what the camera path and the e-stop are about happens in the
    first two trials, so whole sessions take seconds, not a minute."""
    params = tmp_path / "short.toml"
    params.write_text(SHORT_THREE)
    return str(params)


def test_three_options_through_the_whole_distributed_loop(tmp_path: Path) -> None:
    db = tmp_path / "s.sqlite"
    # At 4x a 250 ms staleness bound is 62 ms of wall time: relaxed, as test_run_sim's runs
    # A participant's O order over the three options, by initial (`--order`, as in a study).
    # Seed 3 draws a person who is neither a strategist nor a contrarian: seed 2's strategist
    # could win every control trial with a late switch on a loaded host's timing, so "some
    # control trial ends in dissensus" failed about one run in eight under two CPU burners.
    run = run_nod("run", "--sim", "--options", "3", "--speed", "4", "--seed", "3", "--db",
                  str(db), "--listen", f"tcp/127.0.0.1:{free_port()}", "--stale-ms", "2000",
                  "--order", "GBRRG", timeout=400)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "8 trials of 1 participant(s) stored" in run.stdout
    assert "green" in run.stdout  # the table names the options
    speaker = next((tmp_path / "s.logs").glob("*/speaker.log")).read_text()
    assert "trial 8: go played" in speaker  # the countdown is heard on a table of three too

    store = Store(db)
    try:
        (session,) = [s["session"] for s in store.sessions()]
        assert store.sessions()[0]["status"] == "complete"
        assert store.option_names(session) == ("red", "blue", "green")
        trials = [t for _, t in store.trials(session)]
    finally:
        store.close()
    assert [t.trial for t in trials] == list(range(1, 9))
    # A loaded host's stale inputs may break a trial (repeated, by the paper's rule) and, three
    # times over, leave it interrupted: every choice stored is still one of the three.
    scored = [t for t in trials if not t.interrupted]
    assert len(scored) >= 7, trials
    for t in scored:
        assert t.human in (None, "red", "blue", "green") and t.robot in NAMES, t
    assert sum(t.human is not None for t in scored) >= 7, trials
    control, consensus = trials[:3], trials[3:]
    assert [t.option for t in consensus] == ["green", "blue", "red", "red", "green"]
    # The default person is the fitted one (docs/study.md); this one plays no late switch, so
    # the robot elsewhere ends control trials in dissensus, and 80-97 % of consensus trials end
    # both on O per trial, so a session of five gives four or five in most runs, three in some.
    assert sum(t.outcome in ("D", "DH") for t in control) >= 1, control
    assert sum(t.human == t.option == t.robot for t in consensus) >= 3, consensus
    # The one conductor stores what the paper's stores (test_run_sim): samples with the hand
    # and its landmarks (the z columns NULL: a vector has no faithful scalar,
    # services/experiment/keyspace.py), the countdown as played, the O order given.
    con = sqlite3.connect(db)
    try:
        n_samples = dict(con.execute("SELECT trial, COUNT(*) FROM samples GROUP BY trial"))
        z_values = con.execute("SELECT COUNT(*) FROM samples WHERE z_h IS NOT NULL OR "
                               "z_r IS NOT NULL OR b_r IS NOT NULL").fetchone()[0]
        hands = con.execute("SELECT COUNT(*) FROM samples WHERE detected = 1 AND hand_x IS NOT "
                            "NULL AND length(landmarks) = 168").fetchone()[0]
        cues = con.execute("SELECT trial, cue FROM cues WHERE trial >= 2").fetchall()
        (order,) = con.execute("SELECT options FROM session_orders").fetchone()
    finally:
        con.close()
    assert all(n_samples.get(t.trial, 0) >= 20 for t in scored if t.human), n_samples
    assert z_values == 0 and hands > 100
    assert sorted(set(cues)) == [(t, c) for t in range(2, 9) for c in ("1", "2", "3", "go")]
    assert json.loads(order) == ["green", "blue", "red", "red", "green"]
    out = tmp_path / "csv"
    export = run_nod("export", "--db", str(db), "--out", str(out), timeout=60)
    assert export.returncode == 0, export.stderr
    with (out / "trials.csv").open() as fh:  # one trials.csv, whatever the number of options
        csv_rows = list(csv.DictReader(fh))
    assert [r["trial"] for r in csv_rows] == [str(i) for i in range(1, 9)]
    assert {r["human"] for r in csv_rows} <= {*NAMES, "NA"}
    with (out / "sessions.csv").open() as fh:
        (exported,) = list(csv.DictReader(fh))
    assert exported["options"] == '["red", "blue", "green"]'
    analysis = run_nod("analyze", "study", "--db", str(db), "--json", timeout=120)
    assert analysis.returncode == 0, analysis.stderr
    doc = json.loads(analysis.stdout)  # `nod analyze study` reads the session of three options
    assert doc["options"] == list(NAMES) and doc["participants"] == 1
    assert sum(doc["option_shares"]["4"]["human"].values()) == 1


def test_three_rendered_boxes_found_by_vision(tmp_path: Path) -> None:
    """The camera path: the sim renders three coloured boxes, vision finds them and the hand."""
    db = tmp_path / "s.sqlite"
    run = run_nod("run", "--sim", "--render", "--speed", "2", "--seed", "1", "--params",
                  _short(tmp_path), "--db", str(db), "--listen", f"tcp/127.0.0.1:{free_port()}",
                  "--stale-ms", "2000", timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "3 trials of 1 participant(s) stored" in run.stdout
    vision_log = next((tmp_path / "s.logs").glob("*/vision.log")).read_text()
    assert "found the 3 boxes" in vision_log
    store = Store(db)
    try:
        (session,) = [s["session"] for s in store.sessions()]
        trials = [t for _, t in store.trials(session)]
    finally:
        store.close()
    assert len(trials) == 3 and all(t.robot in NAMES for t in trials)
    assert sum(t.human in NAMES for t in trials) >= 2  # the hand is tracked to its press


def test_an_arm_file_without_a_pose_for_every_option_is_refused_before_anything_starts(
    tmp_path: Path,
) -> None:
    # A real arm runs any table whose options all have press poses in its file (a Feetech bus
    # at three boxes: test_device_faults.py); the paper's red and blue file has no green.
    arm_file = tmp_path / "arm.toml"
    arm_file.write_text(config_toml(FeetechArmConfig(ids=IDS, poses=POSES_BY_N[2])))
    run = run_nod("run", "--sim", "--options", "3", "--arm-driver", "feetech", "--arm-port",
                  "/dev/null", "--arm-config", str(arm_file), "--db",
                  str(tmp_path / "s.sqlite"), "--listen", f"tcp/127.0.0.1:{free_port()}",
                  timeout=60)
    assert run.returncode != 0
    assert f"{arm_file}: the arm file has no press pose for option(s) green" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "s.sqlite").exists()


def _estop_trial_2(tmp_path: Path, params: str) -> tuple[str, Path]:
    """`nod run --sim` of `params`, e-stopped in trial 2 and released: its output and store."""
    db, logs = tmp_path / "s.sqlite", tmp_path / "logs"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run = subprocess.Popen(
        # 2x: trial 2 lasts ~3 s of wall time, enough for `nod estop` to start on a busy host
        [sys.executable, "-m", "services.cli", "run", "--sim", "--speed", "2", "--params",
         params, "--seed", "2", "--db", str(db), "--listen", endpoint,
         "--stale-ms", "1000", "--logs", str(logs)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )

    def rows(sql: str) -> int:
        if not db.exists():
            return 0
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as ro:
            try:
                return int(ro.execute(sql).fetchone()[0])
            except sqlite3.OperationalError:  # the tables are not there yet
                return 0

    out = ""
    try:
        wait_for(lambda: rows("SELECT COUNT(*) FROM trials") >= 1, 120, "trial 1 stored")
        wait_for(lambda: rows("SELECT COUNT(*) FROM open_attempts WHERE trial = 2"), 60,
                 "trial 2 begun")
        engaged = run_nod("estop", "--connect", endpoint, "--reason", "bump", "--timeout", "5",
                          timeout=60)
        assert engaged.returncode == 0, engaged.stdout + engaged.stderr
        wait_for(lambda: rows("SELECT COUNT(*) FROM interruptions WHERE trial = 2"), 60,
                 "trial 2 interrupted by the e-stop")
        released = run_nod("estop", "--connect", endpoint, "--release", "--timeout", "5",
                           timeout=60)
        out, _ = run.communicate(timeout=300)
        assert released.returncode == 0, released.stdout + released.stderr + out
    finally:
        if run.poll() is None:
            run.kill()
    logs_text = "".join(f"--- {p.name}\n{p.read_text()[-3000:]}" for p in sorted(logs.glob("*")))
    assert run.returncode == 0, out + logs_text
    return out, db


def test_an_estop_mid_trial_interrupts_it_and_the_trial_is_repeated(tmp_path: Path) -> None:
    """The N-option conductor's safety: an e-stop breaks trial 2, which is repeated."""
    out, db = _estop_trial_2(tmp_path, _short(tmp_path))
    trials, broken, events = last_session_record(
        db, lambda store, session: [t for _, t in store.trials(session)])
    context = f"{trials}\n{broken}\n{events}\n{out}"
    assert_estop_broke_trial_2_and_every_break_was_repeated(trials, broken, context)
    kinds = [(e.device, e.event) for e in events if e.trial == 2]
    assert ("estop", "estop") in kinds and ("estop", "release") in kinds, context


def test_a_trial_given_up_on_is_stored_interrupted_and_shown_in_the_table(tmp_path: Path) -> None:
    """Not repeated: the e-stopped trial 2 is stored interrupted, published and shown as such."""
    params = tmp_path / "once.toml"
    once = SHORT_THREE.replace("[protocol]\n", "[protocol]\nrepeat_interrupted = false\n")
    params.write_text(once)
    out, db = _estop_trial_2(tmp_path, str(params))
    trials, broken, _ = last_session_record(
        db, lambda store, session: [t for _, t in store.trials(session)])
    context = f"{trials}\n{broken}\n{out}"
    assert [t.trial for t in trials] == [1, 2, 3] and trials[1].interrupted, context
    assert "3 trials of 1 participant(s) stored" in out, context
    table = {int(line.split()[0]): line for line in out.splitlines() if line[:5].strip().isdigit()}
    assert sorted(table) == [1, 2, 3], context  # one row per trial stored, the broken one too
    for t in trials:
        assert table[t.trial].endswith("interrupted") == t.interrupted, context
