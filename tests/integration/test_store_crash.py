"""The store survives kill -9 of its writer: nothing committed is lost, nothing half-written."""

from __future__ import annotations

import os
import random
import signal
import sqlite3
import subprocess
import sys
import time

import pytest

from services.store import Store

SAMPLES_PER_TRIAL = 3000
# A writer that stores a session's trials as the conductor does, one transaction each, and says
# after each commit how many trials are stored.
WRITER = f"""
import sys
from services.store import Sample, Store, TrialRecord
store = Store(sys.argv[1])
store.begin_session("s1", "P01", "rig1", 1, 0, {{}})
for k in range(1, 1000):
    rec = TrialRecord(k, "dissensus", None, "neutral", 0.0, 0.0, k, k + 1, "red", "blue", "D",
                      0, 0, 10, 0, "human pressed")
    samples = [Sample(k * 10**9 + i, True, 0.5, 0.5, 0.1, -0.1, 0.0, 0.5, 0.1)
               for i in range({SAMPLES_PER_TRIAL})]
    store.write_trial("s1", rec, samples)
    print(k, flush=True)
"""


@pytest.mark.integration
@pytest.mark.parametrize("run", range(4))
def test_kill_9_of_the_writer_loses_no_committed_trial(tmp_path, run):
    db = tmp_path / "crash.sqlite"
    proc = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(db)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
    )
    assert proc.stdout is not None
    committed = 0
    while committed < 2:  # let it commit a couple of trials, then kill it mid-write
        committed = int(proc.stdout.readline())
    time.sleep(random.Random(run).uniform(0.0, 0.05))
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(10)
    committed = max([committed, *(int(line) for line in proc.stdout.read().split())])

    store = Store(db)  # opening recovers the WAL
    try:
        assert store.db.execute("PRAGMA integrity_check").fetchone() == ("ok",)
        assert store.interrupted_sessions() == [("s1", len(store.trials("s1")))]
        trials = [rec.trial for _, rec in store.trials("s1")]
        assert trials == list(range(1, len(trials) + 1))  # no gap, no half trial
        assert len(trials) >= committed  # every commit it announced is there
        for k in trials:
            assert len(store.samples("s1", k)) == SAMPLES_PER_TRIAL
    finally:
        store.close()
    # The file is a normal SQLite database for any other reader too.
    with sqlite3.connect(db) as other:
        assert other.execute("SELECT COUNT(*) FROM sessions").fetchone() == (1,)
