"""The e-stop as the rig's most reliable message: acknowledged, reported, and a trial it breaks is
repeated, never scored."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
import time
from functools import partial

import pytest

from services.core import messages as m
from services.core.keys import Keys
from tests.processes import run_nod

from .conftest import (
    ROOT,
    SHORT,
    Collector,
    assert_estop_broke_trial_2_and_every_break_was_repeated,
    free_port,
    last_session_record,
    wait_for,
)

pytestmark = pytest.mark.integration
# `nod estop` waits 1 s for every device's acknowledgement by default, an operator's bound; on a
# loaded test machine a new client's routes alone can take that long. These tests are about who
# acknowledges, so they give it 5 s (the devices' own reaction is bounded in test_safety.py).
ACK_WAIT = ("--timeout", "5")


_nod = partial(run_nod, timeout=60)


def test_estop_with_nobody_listening_fails_and_says_so(router, endpoint):
    t0 = time.monotonic()
    run = _nod("estop", "--connect", endpoint, "--timeout", "0.5")
    assert run.returncode == 1, run.stdout + run.stderr
    assert "actuation: not running" in run.stderr and "eyes: not running" in run.stderr
    assert "NOT by every device" in run.stdout
    assert time.monotonic() - t0 < 15


def test_estop_is_acknowledged_by_actuation_and_eyes(router, endpoint, client, spawn):
    keys = Keys("rig1")
    arm = Collector(client, keys.topic("actuation/state"), m.ArmStateMsg)
    eyes = Collector(client, keys.topic("eyes/state"), m.EyesStateMsg)
    spawn("actuation")
    spawn("eyes")
    # Both up, whatever their state (the e-stop must reach devices in any state, safe or not).
    wait_for(lambda: arm.items and eyes.items, 30, "actuation and eyes publishing their state")
    run = _nod("estop", "--connect", endpoint, "--reason", "test", *ACK_WAIT)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "actuation: obeyed in" in run.stdout and "eyes: obeyed in" in run.stdout
    assert "e-stop: test" in run.stdout  # the reason each device now shows
    release = _nod("estop", "--connect", endpoint, "--release", *ACK_WAIT)
    assert release.returncode == 0, release.stdout + release.stderr
    only_arm = _nod("estop", "--connect", endpoint, "--devices", "actuation", *ACK_WAIT)
    assert only_arm.returncode == 0 and "eyes" not in only_arm.stdout


def test_an_estop_mid_trial_interrupts_it_and_the_trial_is_repeated(tmp_path):
    db = tmp_path / "s.sqlite"
    logs = tmp_path / "logs"
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    params = tmp_path / "short.toml"  # three trials: the e-stop breaks the second
    params.write_text(SHORT)
    run = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "run", "--sim", "--speed", "4", "--seed", "2",
         "--params", str(params), "--db", str(db), "--listen", endpoint, "--stale-ms", "1000",
         "--logs", str(logs)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        def rows(sql: str) -> int:
            if not db.exists():
                return 0
            with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as ro:  # a reader, not a writer
                try:
                    return ro.execute(sql).fetchone()[0]
                except sqlite3.OperationalError:  # the schema is not there yet
                    return 0

        wait_for(lambda: rows("SELECT COUNT(*) FROM trials") >= 1, 120, "trial 1 stored")
        # Trial 2's attempt is on record (its setup): from here on an e-stop breaks it.
        wait_for(
            lambda: rows("SELECT COUNT(*) FROM open_attempts WHERE trial = 2"), 60, "trial 2 begun"
        )
        engaged = _nod("estop", "--connect", endpoint, "--reason", "bump", *ACK_WAIT)
        assert engaged.returncode == 0, engaged.stdout + engaged.stderr
        # Released only once the conductor has broken the trial and stored it so.
        wait_for(
            lambda: rows("SELECT COUNT(*) FROM interruptions WHERE trial = 2"),
            60,
            "trial 2 interrupted by the e-stop",
        )
        released = _nod("estop", "--connect", endpoint, "--release", *ACK_WAIT)
        out, _ = run.communicate(timeout=300)
        assert released.returncode == 0, released.stdout + released.stderr + out + "".join(
            f"--- {p.name}\n{p.read_text()[-3000:]}" for p in sorted(logs.glob("*.log"))
        )
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 0, out + "".join(
        f"--- {p.name}\n{p.read_text()[-3000:]}" for p in sorted(logs.glob("*.log"))
    )
    trials, broken, events = last_session_record(
        db, lambda store, session: [t for _, t in store.trials(session)])
    context = f"{trials}\n{broken}\n{events}\n{out}"
    assert_estop_broke_trial_2_and_every_break_was_repeated(trials, broken, context)
    assert trials[1].robot is not None, context
    kinds = [(e.device, e.event) for e in events if e.trial == 2]
    assert ("estop", "estop") in kinds and ("estop", "release") in kinds, context
    assert ("actuation", "safe_stop") in kinds and ("actuation", "clear") in kinds, context
    report = _nod("report", "--db", str(db))
    assert "trial 2 attempt 1 interrupted" in report.stdout and "attempts=2" in report.stdout
