"""Every interruption prints how to resume, and the printed line does resume.

`nod experiment` stopped by Ctrl-C while it asks for the counter clicks (the trial already
stored) prints `resume with: nod experiment --resume …`; that command goes on at the next trial
and its console shows the trials stored before. `nod run --sim` stopped mid-session prints its
own `nod run --sim --resume …`, which runs the rest of the session: the store has each trial of
it once. The same for a table of three options (`--options 3`, its 8 trials): stopped after
three stored trials and resumed, its store, `nod export` and `nod analyze study` have all 8 by
option name.
"""

from __future__ import annotations

import csv
import json
import os
import shlex
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from contextlib import closing

import pytest

from tests.processes import run_nod, stop_all

from .conftest import ROOT, SHORT, free_port, wait_for

pytestmark = pytest.mark.integration
SPEED = "4"
NAMES = ("red", "blue", "green")  # `--options 3`'s default option set


class Output:
    """Everything a process writes on one pipe, read as it comes (a prompt has no newline)."""

    def __init__(self, pipe) -> None:
        self.text = ""
        self._pipe = pipe
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        while chunk := os.read(self._pipe.fileno(), 4096):
            self.text += chunk.decode(errors="replace")


def _resume_line(stderr: str) -> list[str]:
    lines = [ln for ln in stderr.splitlines() if ln.startswith("resume with: ")]
    assert len(lines) == 1, stderr
    return shlex.split(lines[0].removeprefix("resume with: "))


def _trials(db, session: str) -> list[tuple[int, int | None]]:
    con = sqlite3.connect(db)
    try:
        return con.execute(
            "SELECT trial, clicks FROM trials WHERE session = ? ORDER BY trial", (session,)
        ).fetchall()
    finally:
        con.close()


def _stored(db) -> int:
    """Trials stored so far in a store being written (0 before its tables are there)."""
    if not db.exists():
        return 0
    with closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True)) as ro:
        try:
            return int(ro.execute("SELECT COUNT(*) FROM trials").fetchone()[0])
        except sqlite3.OperationalError:
            return 0


def _status(db, session: str) -> str:
    con = sqlite3.connect(db)
    try:
        row = con.execute("SELECT status FROM sessions WHERE session = ?", (session,)).fetchone()
        return row[0]
    finally:
        con.close()


def test_ctrl_c_at_the_click_prompt_prints_the_resume_line_and_it_resumes(
    router, endpoint, tmp_path
):
    params = tmp_path / "short.toml"
    params.write_text(SHORT)
    db = tmp_path / "s.sqlite"
    clock = ["--speed", SPEED, "--epoch-ns", str(time.time_ns()), "--params", str(params)]
    rig = []
    for service in ("decision", "actuation", "eyes", "sim"):
        safety = ["--stale-ms", "2000"] if service in ("actuation", "eyes") else []
        rig.append(subprocess.Popen(
            [sys.executable, "-m", "services.cli", service, "--connect", endpoint, *clock,
             *safety],
            cwd=ROOT, stdout=(tmp_path / f"{service}.log").open("w"), stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
        ))
    conductor = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "experiment", "--connect", endpoint, *clock,
         "--db", str(db), "--session", "s-ctrl-c", "--console", "lines"],
        cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )
    try:
        out, err = Output(conductor.stdout), Output(conductor.stderr)
        wait_for(lambda: "trial 1: counter clicks" in out.text, 120, "trial 1's prompt")
        conductor.stdin.write(b"7\n")
        conductor.stdin.flush()
        wait_for(lambda: "trial 2: counter clicks" in out.text, 60, "trial 2's prompt")
        conductor.send_signal(signal.SIGINT)  # the operator's Ctrl-C while asked
        assert conductor.wait(10) == 130
        wait_for(lambda: "resume with: " in err.text, 5, "the resume line")
        # Normal trials raise no alarm: no warning before the operator's interruption.
        before = err.text.split("WARNING nod.experiment: session s-ctrl-c interrupted")[0]
        assert "WARNING" not in out.text and "WARNING" not in before, out.text + err.text
        argv = _resume_line(err.text)
        assert argv[:4] == ["nod", "experiment", "--resume", "s-ctrl-c"]
        assert argv[argv.index("--db") + 1] == str(db)
        assert argv[argv.index("--connect") + 1] == endpoint
        assert "--epoch-ns" in argv and "--params" in argv and "--participant" not in argv
        assert _status(db, "s-ctrl-c") == "aborted"

        resumed = run_nod(*argv[1:], input="\n\n\n", timeout=180)
        assert resumed.returncode == 0, resumed.stdout + resumed.stderr
        lines = resumed.stdout.splitlines()
        # Trial 2 had ended and was stored before its prompt: the Ctrl-C there left it stored
        # once, clicks not entered, and the resume goes on with trial 3 (the participant never
        # sees a trial twice). The console goes on from the stored trials 1 and 2.
        second = next(i for i, ln in enumerate(lines) if ln.startswith("trial 2: robot"))
        assert second < next(i for i, ln in enumerate(lines) if ln.startswith("trial 3/3"))
        assert not any(ln.startswith("trial 2/3") for ln in lines), resumed.stdout
        assert _trials(db, "s-ctrl-c") == [(1, 7), (2, None), (3, None)]
        assert _status(db, "s-ctrl-c") == "complete"
        con = sqlite3.connect(db)
        try:
            broken = con.execute("SELECT trial, attempt, reason FROM interruptions").fetchall()
            attempts = con.execute("SELECT trial, attempts FROM trials ORDER BY trial").fetchall()
        finally:
            con.close()
        assert broken == [], broken  # nothing interrupted: the stop came after the trial
        assert attempts == [(1, 1), (2, 1), (3, 1)]
    finally:
        stop_all([conductor, *rig])


@pytest.mark.parametrize(
    ("options", "stop_after", "n_trials"),
    [(None, 1, 3), (3, 3, 8)],
    ids=["paper", "three-options"],
)
def test_nod_run_interrupted_prints_its_resume_line_and_resumes(
    tmp_path, options, stop_after, n_trials
):
    db = tmp_path / "run.sqlite"
    if options is None:  # the paper's: SHORT's three trials
        params = tmp_path / "short.toml"
        params.write_text(SHORT)
        table = ["--params", str(params)]
    else:  # a table of three: its default schedule of 8 trials
        table = ["--options", str(options)]
    listen = f"tcp/127.0.0.1:{free_port()}"
    run = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "run", "--sim", "--speed", SPEED, "--stale-ms",
         "2000", *table, "--db", str(db), "--listen", listen],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
    )
    try:
        out, err = Output(run.stdout), Output(run.stderr)
        wait_for(lambda: _stored(db) >= stop_after, 300, f"{stop_after} trial(s) stored")
        run.send_signal(signal.SIGINT)
        assert run.wait(30) == 130, out.text + err.text
        wait_for(lambda: "resume with: " in err.text, 5, "the resume line")
    finally:
        stop_all([run])
    argv = _resume_line(err.text)
    assert argv[:5] == ["nod", "run", "--sim", "--resume", argv[4]]
    session = argv[4]
    assert argv[argv.index("--db") + 1] == str(db)
    assert argv[argv.index(table[0]) + 1] == table[1]  # the same params, the same table
    assert stop_after <= len(_trials(db, session)) < n_trials
    backup = db.with_name(db.name + ".backup")  # the stopped session's end backed the store up
    assert _trials(backup, session) == _trials(db, session)

    resumed = run_nod(*argv[1:], timeout=400)
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert f"resuming session {session}" in resumed.stdout
    # the table went on
    assert f"{n_trials} trials of 1 participant(s) stored" in resumed.stdout
    assert [t for t, _ in _trials(db, session)] == list(range(1, n_trials + 1))  # each, once
    assert _status(db, session) == "complete"
    con = sqlite3.connect(db)
    assert con.execute("SELECT COUNT(*) FROM sessions").fetchone()[0] == 1
    con.close()
    assert _status(backup, session) == "complete" and _trials(backup, session) == _trials(
        db, session)
    # A complete session is not resumed again: refused in one line, its finish time kept.
    finished = _finished(db)
    again = run_nod(*argv[1:], timeout=60)
    assert again.returncode == 2 and "is complete" in again.stderr, again.stdout + again.stderr
    assert len(again.stderr.strip().splitlines()) == 1, again.stderr
    assert _finished(db) == finished
    if options is not None:
        _assert_read_by_option_name(tmp_path, db, session, n_trials)


def _assert_read_by_option_name(tmp_path, db, session: str, n_trials: int) -> None:
    """The resumed session of three options: stored, exported and analysed by option name."""
    with closing(sqlite3.connect(db)) as con:
        (names,) = con.execute(
            "SELECT names FROM option_sets WHERE session = ?", (session,)).fetchone()
        stored = con.execute(
            "SELECT option, human, robot FROM trials WHERE session = ? AND interrupted = 0",
            (session,)).fetchall()
    assert tuple(json.loads(names)) == NAMES
    assert stored and all(v in (None, *NAMES) for row in stored for v in row), stored
    assert {row[2] for row in stored} <= set(NAMES) and "green" in {
        v for row in stored for v in row}, stored
    out = tmp_path / "csv"
    export = run_nod("export", "--db", str(db), "--out", str(out), timeout=60)
    assert export.returncode == 0, export.stderr
    with (out / "trials.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [r["trial"] for r in rows] == [str(i) for i in range(1, n_trials + 1)]
    assert {r["robot"] for r in rows} <= {*NAMES, "NA"} and "green" in {r["option"] for r in rows}
    analysis = run_nod("analyze", "study", "--db", str(db), "--json", timeout=120)
    assert analysis.returncode == 0, analysis.stderr
    doc = json.loads(analysis.stdout)
    assert doc["options"] == list(NAMES) and doc["participants"] == 1


def _finished(db) -> list[tuple[str, int | None]]:
    with closing(sqlite3.connect(db)) as con:
        return con.execute("SELECT status, finished_ns FROM sessions").fetchall()


def test_a_bad_nod_run_resume_is_a_one_line_error(tmp_path):
    db = tmp_path / "empty.sqlite"
    for extra, says in (
        (["--resume", "nope"], "no session 'nope'"),
        (["--resume", "nope", "--participant", "P02"], "leave out --participant"),
        (["--resume", "nope", "--participants", "2"], "leave out --participants"),
    ):
        res = run_nod("run", "--sim", "--db", str(db), *extra, timeout=60)
        assert res.returncode == 2, res.stdout + res.stderr
        assert len(res.stderr.strip().splitlines()) == 1 and says in res.stderr, res.stderr
