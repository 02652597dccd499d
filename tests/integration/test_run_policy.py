"""A robot policy on the distributed rig: `nod run --sim --policy FILE --estimate …`.

One recorded three-trial session at 4x with an adaptive policy (a small table) and `nod estimate`
(a small cached estimator), frozen by the operator (`nod experiment freeze`) once trial 1 is
stored. Checked: the policy and its file's hash stored with the session, the settings of every
trial stored, inside the envelope and played (the trial's gaze level), the freeze confirmed and
holding, one estimate per trial stored with its interval, and both keys in the recording.
"""

from __future__ import annotations

import csv
import hashlib
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader

from services.core import messages as m
from services.core.config import load_params
from services.model.policy import PolicySettings
from tests.processes import run_nod, stop_all

from .conftest import ROOT, SHORT, free_port, wait_for

pytestmark = pytest.mark.integration

POLICY = """
kind = "adaptive"
gaze_levels = ["neutral", "extreme"]
b_stars = [4.54, 6.0]
u_rs = [2.24]
table_people = 24
table_seed = 900000001
"""
TABLE = 20  # the estimator's simulated people: the least `nod fit` takes


def _rows(db: Path, sql: str) -> list[tuple]:
    con = sqlite3.connect(db)
    try:
        return con.execute(sql).fetchall()
    finally:
        con.close()


def _stored(db: Path) -> int:
    """Trials stored so far (0 while the conductor has not yet made the file or its tables)."""
    try:
        return _rows(db, "SELECT count(*) FROM trials")[0][0] if db.exists() else 0
    except sqlite3.OperationalError:  # the file exists, its schema not yet
        return 0


@pytest.fixture(scope="module")
def ran(tmp_path_factory) -> dict:
    folder = tmp_path_factory.mktemp("policy")
    params, policy, db = folder / "short.toml", folder / "mine.toml", folder / "s.sqlite"
    params.write_text(SHORT)
    policy.write_text(POLICY)
    env = {**os.environ, "NOD_POLICY_CACHE": str(folder / "tables"),
           "NOD_CACHE_DIR": str(folder / "fit")}
    # The estimator's table and training, once and cached, as a lab would before a study
    # (`nod estimate` then starts ready): the session's estimates are then owed from trial 1.
    warm = subprocess.run(
        [sys.executable, "-c",
         "import sys; from pathlib import Path; "
         "from services.cohort.person import load_cohort_params; "
         "from services.fit.pipeline import prepare_by_length; "
         "from services.fit.prior import load_prior; "
         "from services.fit.simulate import Population; "
         f"prepare_by_length(Population(load_cohort_params(None), load_prior(None)), {TABLE}, "
         "lambda f, jobs: [f(j) for j in jobs], Path(sys.argv[1]))", str(folder / "fit")],
        cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    assert warm.returncode == 0, warm.stderr
    port = free_port()
    run = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "run", "--sim", "--speed", "4", "--seed", "3",
         "--db", str(db), "--listen", f"tcp/127.0.0.1:{port}", "--stale-ms", "2000",
         "--params", str(params), "--record", str(folder / "rec"), "--policy", str(policy),
         "--estimate", f"--table {TABLE}"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        wait_for(lambda: _stored(db) >= 1, timeout=240, what="trial 1 stored")
        freeze = run_nod("experiment", "freeze", "--connect", f"tcp/127.0.0.1:{port}",
                         "--rig", "rig1", "--timeout", "30", timeout=60)
        out, _ = run.communicate(timeout=300)
    finally:
        stop_all([run])
    assert run.returncode == 0, out
    (mcap,) = sorted((folder / "rec").glob("*.mcap"))
    return {"db": db, "policy": policy, "params": params, "freeze": freeze, "mcap": mcap,
            "out": out, "cache": folder / "fit"}


def test_the_policy_and_each_trials_settings_are_stored_inside_the_envelope(ran):
    db = ran["db"]
    ((session, name, sha, _kind),) = _rows(db, "SELECT * FROM policy_sessions")
    assert (name, sha) == ("mine", hashlib.sha256(ran["policy"].read_bytes()).hexdigest())
    settings = {t: PolicySettings(b, g, u) for _, t, b, g, u in
                _rows(db, "SELECT * FROM policy_trials ORDER BY trial")}
    assert sorted(settings) == [1, 2, 3]
    cfg = load_params(ran["params"])
    assert all(cfg.policy.contains(s) for s in settings.values())
    # the control trial keeps the paper's settings; a trial's gaze level is the one it played
    assert settings[1] == PolicySettings(cfg.decision.bias.threshold(2.24), "neutral", 2.24)
    played = dict(_rows(db, f"SELECT trial, gaze_level FROM trials WHERE session = '{session}'"))
    assert played == {t: s.gaze_level for t, s in settings.items()}
    (prov,) = _rows(db, "SELECT policy_file, policy_sha256 FROM provenance")
    assert prov == ("mine", sha)


def test_the_operators_freeze_is_confirmed_and_holds(ran):
    freeze = ran["freeze"]
    assert freeze.returncode == 0, freeze.stdout + freeze.stderr
    assert "frozen" in freeze.stdout
    rows = _rows(ran["db"], "SELECT trial, b_star, gaze_level, u_r FROM policy_trials "
                 "ORDER BY trial")
    assert rows[2][1:] == rows[1][1:], "trial 3 runs the settings held since the freeze"
    policy = _messages(ran["mcap"], "experiment/policy", m.PolicyMsg)
    assert any(p.frozen for p in policy)
    assert all(p.frozen for p in policy if p.trial == 3)


def test_one_estimate_per_trial_is_stored_and_recorded(ran):
    rows = _rows(ran["db"], "SELECT trial, trials_seen, name, estimate, low, high, probability "
                 "FROM person_estimates ORDER BY trial")
    assert sorted({r[0] for r in rows}) == [1, 2, 3], ran["out"]
    for trial, seen, _name, est, low, high, prob in rows:
        assert seen == trial
        assert low <= est <= high
        assert prob is None or 0.0 <= prob <= 1.0
    names = {r[2] for r in rows}
    assert {"gaze_gain", "speed"} <= names or len(names) >= 4, names
    recorded = _messages(ran["mcap"], "estimate/person", m.PersonEstimate)
    assert [e.trial for e in recorded] == [1, 2, 3]
    policy = _messages(ran["mcap"], "experiment/policy", m.PolicyMsg)
    assert {p.trial for p in policy} == {1, 2, 3}


def test_the_live_estimate_is_nod_fits_estimate_on_the_stored_trials(ran):
    # The same estimator on the same data: what `nod estimate` built from the fabric equals
    # what the fit reads from the store afterwards (`services.fit.data.read_study`).
    from services.cohort.person import load_cohort_params
    from services.fit.data import read_study
    from services.fit.estimator import estimate_after
    from services.fit.pipeline import prepare_by_length
    from services.fit.prior import load_prior
    from services.fit.simulate import Population

    (person,) = read_study(ran["db"]).people
    pop = Population(load_cohort_params(None), load_prior(None))
    estimators = prepare_by_length(pop, TABLE, lambda f, jobs: [f(j) for j in jobs],
                                   ran["cache"])[1]
    offline = estimate_after(estimators, 3, person.paths, person.layout)
    live = {r[0]: r[1:] for r in _rows(ran["db"], "SELECT name, estimate, low, high FROM "
                                      "person_estimates WHERE trial = 3")}
    assert sorted(live) == sorted(offline.names)
    for j, name in enumerate(offline.names):
        want = (offline.estimate[0, j], offline.low[0, j], offline.high[0, j])
        assert live[name] == pytest.approx(want, rel=1e-9, abs=1e-12), name


def test_the_policy_and_the_estimates_are_in_the_export(ran, tmp_path):
    out, bids = tmp_path / "csv", tmp_path / "bids"
    done = run_nod("export", "--db", str(ran["db"]), "--out", str(out), "--bids", str(bids),
                   timeout=120)
    assert done.returncode == 0, done.stderr
    with (out / "policies.csv").open() as fh:
        policies = list(csv.DictReader(fh))
    assert [(r["trial"], r["policy"]) for r in policies] == [(str(t), "mine") for t in (1, 2, 3)]
    with (out / "estimates.csv").open() as fh:
        estimates = list(csv.DictReader(fh))
    stored = _rows(ran["db"], "SELECT count(*) FROM person_estimates")[0][0]
    assert len(estimates) == stored and {r["trial"] for r in estimates} == {"1", "2", "3"}
    (beh,) = bids.rglob("*_beh.tsv")
    with beh.open() as fh:
        rows = list(csv.DictReader(fh, delimiter="\t"))
    assert [float(r["policy_b_star"]) for r in rows] == [float(p["b_star"]) for p in policies]
    assert all(r["estimate_trials_seen"] == r["trial"] for r in rows)


def _messages(path: Path, topic: str, cls: type[m.Message]) -> list:
    with path.open("rb") as fh:
        return [m.decode_json(cls, msg.data) for _, ch, msg in make_reader(fh).iter_messages()
                if ch.topic == f"nod/rig1/{topic}"]


def test_a_freeze_without_a_conductor_fails_in_one_line(tmp_path):
    gone = run_nod("experiment", "freeze", "--connect", f"tcp/127.0.0.1:{free_port()}",
                   "--rig", "rig1", "--timeout", "1", timeout=60)
    assert gone.returncode != 0
    assert len(gone.stderr.strip().splitlines()) == 1, gone.stderr
