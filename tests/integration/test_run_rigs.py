"""`nod run --sim --rigs 2`: two simulated rigs at once on one router, one study in two stores.

Over the paper's two options and over a table of three (`--options 3`, every rig's).
"""

from __future__ import annotations

import json
import re
import sqlite3
import subprocess
import sys
import threading

import pytest

from services.store import Store
from services.tools import lab_status
from tests.processes import run_nod, stop_all

from .conftest import ROOT, SHORT, connect_when_listening, free_port

pytestmark = pytest.mark.integration
# option count: (the option set, trials per session). Two: the short paper schedule (SHORT);
# three: `--options 3` alone, its default 8 trials (the study analysis needs trials 1-3 control,
# 4-8 consensus at N > 2), so each rig gets the table from the flag passed on to it.
TABLES = {2: (("red", "blue"), 3), 3: (("red", "blue", "green"), 8)}


@pytest.mark.parametrize("n", sorted(TABLES), ids=lambda n: f"{n} options")
def test_two_rigs_run_their_share_of_the_study_at_once_into_their_own_stores(tmp_path, n) -> None:
    names, n_trials = TABLES[n]
    params = tmp_path / "short.toml"
    params.write_text(SHORT)
    table = ["--params", str(params)] if n == 2 else ["--options", str(n)]
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    db = tmp_path / "study.sqlite"
    run = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "run", "--sim", "--rigs", "2", "--participants",
         "3", "--seed", "5", "--speed", "8", *table, "--listen", endpoint,
         "--stale-ms", "2000", "--db", str(db)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    seen: set[str] = set()  # the rigs the lab view showed running a participant
    try:
        session = connect_when_listening(endpoint, alive=lambda: run.poll() is None)
        stop = threading.Event()
        while run.poll() is None and seen != {"rig1", "rig2"}:
            doc = lab_status.report(lab_status.observe(session, 1.0, stop), 0)
            seen |= {r["rig"] for r in doc["rigs"] if r["participant"]}
        session.close()
        out, _ = run.communicate(timeout=600)
    finally:
        stop_all([run])
    assert run.returncode == 0, out[-3000:]
    assert seen == {"rig1", "rig2"}, f"the lab view saw only {seen} run a participant"
    stores = [tmp_path / "study-rig1.sqlite", tmp_path / "study-rig2.sqlite"]
    rows, spans = [], {}
    for path in stores:
        con = sqlite3.connect(path)
        rows += con.execute("SELECT participant, rig, seed, status, (SELECT COUNT(*) FROM trials "
                            "t WHERE t.session = s.session) FROM sessions s").fetchall()
        for rig, start, end in con.execute("SELECT rig, started_ns, finished_ns FROM sessions"):
            spans.setdefault(rig, []).append((start, end))
        con.close()
        store = Store(path)  # each rig's sessions ran the run's table
        try:
            assert {store.option_names(s["session"]) for s in store.sessions()} == {names}
        finally:
            store.close()
    # At once: some session of rig1 ran while one of rig2 did (both rigs share nod run's clock).
    assert any(a0 < b1 and b0 < a1 for a0, a1 in spans["rig1"] for b0, b1 in spans["rig2"]), spans
    # The study's people in contiguous blocks, each with the seed `--rigs 1` would give it.
    assert sorted(rows) == [("P01", "rig1", 5, "complete", n_trials),
                            ("P02", "rig1", 6, "complete", n_trials),
                            ("P03", "rig2", 7, "complete", n_trials)]
    assert f"nod analyze study --db {stores[0]} --db {stores[1]}" in out
    # Each stored trial of each rig was a line on the way, naming its rig and participant.
    said = {ln.split(" [")[0] for ln in out.splitlines()  # a broken, repeated trial: twice
            if re.match(r"rig\d P\d\d trial", ln)}
    assert sorted(said) == [f"{rig} {who} trial {t}/{n_trials}" for rig, who in (
        ("rig1", "P01"), ("rig1", "P02"), ("rig2", "P03")) for t in range(1, n_trials + 1)], (
        out[-3000:])
    # a consensus trial's line names its O by the table's names
    assert any(f"O={names[-1]}]" in ln for ln in out.splitlines()), out[-3000:]
    study = run_nod("analyze", "study", "--db", str(stores[0]), "--db", str(stores[1]), "--json")
    assert study.returncode == 0, study.stderr
    doc = json.loads(study.stdout)
    assert doc["participants"] == 3 and doc["rigs"] == {"rig1": 2, "rig2": 1}


def test_what_rigs_cannot_take_is_one_line() -> None:
    for args, says in ((["--rigs", "3", "--participants", "2"], "at least one participant"),
                       (["--rigs", "2", "--participants", "2", "--participant", "P09"],
                        "leave out --participant"),
                       (["--rigs", "2", "--participants", "2", "--arm-driver", "feetech"],
                        "one device cannot serve several rigs")):
        res = run_nod("run", "--sim", *args, timeout=60)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and says in res.stderr, (
            args, res.stderr)
