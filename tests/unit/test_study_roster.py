"""The roster against the store (done, running, aborted, left; who is next), consent, the order
stored with a session, and the refusals — no consent, a reused id — each in one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from services.experiment import service as experiment
from services.experiment.keyspace import key_space
from services.experiment.order import participant_problem, session_keys
from services.model.params import NodConfig
from services.model.protocol import default_schedule
from services.model.schedule import OptionsSchedule
from services.store import Store, TrialRecord
from services.store.participants import (
    consent_of,
    next_free_ids,
    order_of_session,
    record_consent,
    record_order,
)
from services.study import cli
from services.study.roster import roster
from services.study.studyfile import load, make_study, write


def _trial(i: int) -> TrialRecord:
    return TrialRecord(i, "dissensus", None, "neutral", 0.0, 0.0, 1, 2, "red", "blue", "D",
                       0, 0, None, 0, "human pressed")


def _session(store: Store, session: str, who: str, status: str | None, trials: int, t: int) -> None:
    store.begin_session(session, who, "rig1", 1, t, {})
    for i in range(1, trials + 1):
        store.write_trial(session, _trial(i), [])
    if status is not None:
        store.finish_session(session, t + 1, status)


def _protocol(n: int):
    """The default protocol of n options: the paper's trials at two, a schedule of N beyond."""
    return default_schedule() if n == 2 else OptionsSchedule.default(n)


# The tests that run a study over any option set take `study_db` with the option count
OVER_N = pytest.mark.parametrize("study_db", [2, 3], indirect=True, ids=lambda n: f"{n} options")


@pytest.fixture
def study_db(tmp_path: Path, request) -> tuple[Path, Path]:
    """A 6-person study: P01 done, P02 aborted after 4 trials, P03 running, P04-P06 left.

    Of the paper's two options, or of as many as the test's parameter says (`OVER_N`).
    """
    path, db = tmp_path / "study.toml", tmp_path / "s.sqlite"
    study = make_study("pilot", _protocol(getattr(request, "param", 2)), 6, seed=4)
    write(study, path)
    store = Store(db)
    _session(store, "s1", "P01", "complete", 8, 10)
    record_order(store, "s1", "P01", study.participants[0].order, None, 10)
    _session(store, "s2", "P02", "aborted", 4, 20)
    _session(store, "s3", "P03", None, 2, 30)
    _session(store, "x9", "PILOT", "complete", 8, 40)
    store.close()
    return path, db


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


@OVER_N
def test_each_participant_is_done_running_aborted_or_left(study_db):
    path, db = study_db
    study, store = load(path), Store(db)
    r = roster(study, store)
    assert [s.status for s in r.standings] == ["done", "aborted", "running", "left", "left", "left"]
    assert r.counts() == {"done": 1, "running": 1, "aborted": 1, "left": 3, "withdrawn": 0}
    assert [s.session.trials for s in r.standings[:3]] == [8, 4, 2]
    assert r.next().entry.id == "P04"
    assert r.strangers == {"PILOT": 1}
    assert not r.standings[0].order_mismatch
    record_consent(store, "P04", False, 5, {})  # refused: not next
    assert roster(study, store).next().entry.id == "P05"
    assert next_free_ids(store, 3) == ["P04", "P05", "P06"]
    store.close()


@OVER_N
def test_consent_is_stored_with_demographics_and_start_refuses_without_it(study_db, capsys):
    path, db = study_db
    assert cli.main(["start", str(path), "--db", str(db), "--dry-run"]) == 2
    err = _one_line_error(capsys)
    assert "P04 has no consent on record: nod study consent" in err and "--yes" in err
    assert cli.main(["consent", str(path), "--db", str(db), "--participant", "P04", "--yes",
                     "--age", "25-34", "--handedness", "right", "--notes", "wears glasses"]) == 0
    store = Store(db)
    c = consent_of(store, "P04")
    assert c is not None and c.consent and c.consented_ns > 0
    assert c.demographics == {"age": "25-34", "handedness": "right", "notes": "wears glasses"}
    store.close()
    capsys.readouterr()
    assert cli.main(["start", str(path), "--db", str(db), "--dry-run", "--",
                     "--connect", "tcp/10.0.0.2:7447", "--clicks", "prompt"]) == 0
    out = capsys.readouterr().out
    study = load(path)
    entry = study.participants[3]  # by initials in the paper's study, by names over N options
    order = entry.letters if study.paper else ",".join(entry.order)
    options = "" if study.paper else f" --options {len(study.options)}"  # a table of N boxes
    assert (f"nod experiment --db {db} --participant P04 --order {order} --study {path}"
            f"{options} --connect" in out)
    assert cli.main(["consent", str(path), "--db", str(db), "--participant", "P04", "--no"]) == 0
    capsys.readouterr()
    assert cli.main(["start", str(path), "--db", str(db), "--participant", "P04"]) == 2
    assert "P04 withdrew from the study" in _one_line_error(capsys)  # had consented: withdrawn
    assert cli.main(["consent", str(path), "--db", str(db), "--participant", "P05", "--no"]) == 0
    assert "P05: consent refused" in capsys.readouterr().out  # never consented: a refusal
    assert cli.main(["start", str(path), "--db", str(db), "--participant", "P05"]) == 2
    assert "P05 refused or withdrew consent" in _one_line_error(capsys)
    assert cli.main(["consent", str(path), "--db", str(db), "--participant", "P99", "--yes"]) == 2
    assert "'P99' is not in study pilot" in _one_line_error(capsys)


def test_a_reused_id_is_refused_unless_again_says_why(study_db, capsys):
    path, db = study_db
    store = Store(db)
    for p in ("P01", "P02"):
        record_consent(store, p, True, 1, {})
    store.close()
    start = ["start", str(path), "--db", str(db), "--dry-run", "--participant"]
    assert cli.main([*start, "P01"]) == 2
    err = _one_line_error(capsys)
    assert "P01 already has a complete session (s1, 8 trials)" in err and "--again" in err
    assert cli.main([*start, "P02"]) == 2
    assert "aborted session s2 after 4 trial(s)" in (err := _one_line_error(capsys))
    assert "nod experiment --resume s2" in err
    assert cli.main([*start, "P01", "--again", " "]) == 2
    assert "--again needs a reason" in _one_line_error(capsys)
    assert cli.main([*start, "P01", "--again", "fire alarm at trial 5"]) == 0
    assert "--again 'fire alarm at trial 5'" in capsys.readouterr().out
    assert cli.main([*start, "P01", "--again", "x", "--", "--order", "RRRRR"]) == 2
    assert "--order after --" in _one_line_error(capsys)


def test_nod_experiment_and_nod_run_refuse_a_participant_who_is_done(study_db, capsys):
    from services import run

    _, db = study_db
    assert experiment.main(["--db", str(db), "--participant", "P01", "--console", "off"]) == 2
    err = _one_line_error(capsys)
    assert err.startswith("nod experiment: participant P01 already has a complete session (s1")
    assert run.main(["--sim", "--db", str(db), "--participant", "P01"]) == 2
    assert "nod run: participant P01 already has a complete session" in _one_line_error(capsys)
    store = Store(db)
    assert participant_problem(store, "P01", "a retest", None) is None  # --again
    assert participant_problem(store, "P02", None, None) is None  # aborted: its conductor's call
    assert participant_problem(store, "P01", None, "s1") is None  # --resume
    store.close()


ORDERS = {  # option count: (an --order, the order it is, another --order)
    2: ("RBBRB", ("red", "blue", "blue", "red", "blue"), "BRRBR"),
    3: ("green,red,blue,blue,green", ("green", "red", "blue", "blue", "green"), "RBGRB"),
}


@pytest.mark.parametrize("n", sorted(ORDERS), ids=lambda n: f"{n} options")
def test_the_order_a_session_runs_and_a_resume_keeps_it(tmp_path, n):
    store = Store(tmp_path / "o.sqlite")
    keys = key_space(NodConfig(), None if n == 2 else OptionsSchedule.default(n))
    text, order, other = ORDERS[n]
    assert session_keys(keys, store, None, None) is keys
    turned = session_keys(keys, store, text, None)
    assert turned.order() == order
    # trial 4 now converges on another O: the clock's gaze (its yaw) turns toward it
    assert turned.trials[3].yaw != keys.trials[3].yaw
    if n == 2:
        assert turned.trials[4].yaw == pytest.approx(-0.53)  # trial 5 looks toward blue
    assert [turned.trial(t)[1] for t in turned.trials][3:] == list(order)
    record_order(store, "s7", "P07", turned.order(), None, 1)
    assert order_of_session(store, "s7") == order
    resumed = session_keys(keys, store, None, "s7")  # no --order: the stored one
    assert resumed.order() == order and resumed.trials == turned.trials
    with pytest.raises(ValueError, match=f"session s7 runs the order {','.join(order)}"):
        session_keys(keys, store, other, "s7")
    with pytest.raises(ValueError, match="--order needs O for each of the 5 consensus trials"):
        session_keys(keys, store, "purple" * 5, None)
    store.close()


@OVER_N
def test_status_lists_everyone_with_json(study_db, capsys):
    path, db = study_db
    assert cli.main(["status", str(path), "--db", str(db)]) == 0
    out = capsys.readouterr().out
    assert "1 done, 1 running, 1 aborted, 3 left; next: P04" in out
    assert "resume: nod experiment --resume s2" in out
    assert "participants not in the study: PILOT (1)" in out
    assert cli.main(["status", str(path), "--db", str(db), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    options = list(load(path).options)  # red, blue (, green)
    assert doc["next"] == "P04" and doc["block"] == 5 * len(options)  # n consensus x N options
    assert doc["options"] == options
    p1 = doc["participants"][0]
    assert p1["status"] == "done" and p1["sessions"][0]["order"] == p1["order"]
    assert cli.main(["next", str(path), "--db", str(db)]) == 0
    assert capsys.readouterr().out.startswith("P04 (slot 4 of 6): O of trials 4,5,6,7,8 = ")


def test_a_study_of_n_options_runs_only_the_protocol_of_its_options(tmp_path, capsys):
    path = tmp_path / "s.toml"
    assert cli.main(["init", str(path), "--participants", "3", "--seed", "1", "--options",
                     "3"]) == 0
    assert "3 cyclic relabellings of red, blue, green" in capsys.readouterr().out
    params = tmp_path / "four.toml"  # the same study file, pointed at a protocol of four boxes
    params.write_text('[protocol]\noptions = ["red", "blue", "green", "yellow"]\n')
    path.write_text(path.read_text().replace("[study]\n", '[study]\nparams = "four.toml"\n'))
    assert cli.main(["status", str(path), "--db", str(tmp_path / "s.sqlite")]) == 2
    err = _one_line_error(capsys)
    assert "options ['red', 'blue', 'green'] are not those of" in err and "yellow" in err


def test_init_refuses_to_overwrite_a_roster(tmp_path, capsys):
    path = tmp_path / "s.toml"
    assert cli.main(["init", str(path), "--participants", "10", "--seed", "1"]) == 0
    assert "10 participants P01–P10" in capsys.readouterr().out
    before = path.read_text()
    assert cli.main(["init", str(path), "--participants", "12"]) == 2
    assert "exists" in _one_line_error(capsys)
    assert path.read_text() == before
    assert cli.main(["init", str(path), "--participants", "12", "--force"]) == 0
    assert len(load(path).participants) == 12
