"""`nod fit` end to end on a tiny simulated study, and its one-line answers to bad input."""

from __future__ import annotations

import csv
import json

import pytest

from services.experiment.export import main as export_main
from services.fit.cli import main
from services.sim import cohort
from services.store import Sample, Store, TrialRecord
from services.store.fits import read_fits


def _record(trial: int, interrupted: bool = False) -> TrialRecord:
    return TrialRecord(trial, "dissensus", None, "neutral", 0.0, 0.0, 10**9, 2 * 10**9, "red",
                       "blue", "D", 0, 0, 10, 0, "human pressed", interrupted=interrupted)


def _one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("nod fit: error: ")
    return err


def test_an_empty_store_is_one_line(tmp_path, capsys):
    db = tmp_path / "empty.sqlite"
    Store(db).close()
    assert main(["--db", str(db)]) == 2
    assert "holds no sessions" in _one_line(capsys)


def test_a_missing_database_is_one_line(tmp_path, capsys):
    assert main(["--db", str(tmp_path / "nope.sqlite")]) == 2
    assert "no such database" in _one_line(capsys)


def test_a_store_without_landmarks_is_one_line(tmp_path, capsys):
    db = tmp_path / "trials-only.sqlite"
    store = Store(db)
    store.begin_session("s1", "P01", "rig1", 1, 0, {})
    for k in (1, 2):
        store.write_trial("s1", _record(k), [])  # trials, but no hand sample kept
    store.close()
    assert main(["--db", str(db), "--min-trials", "1"]) == 2  # a running session: let it in
    assert "stores no hand samples (landmarks)" in _one_line(capsys)


def test_a_participant_with_no_complete_trial_is_one_line(tmp_path, capsys):
    db = tmp_path / "broken.sqlite"
    store = Store(db)
    store.begin_session("s1", "P01", "rig1", 1, 0, {})
    store.write_trial("s1", _record(1), [])  # scored, but no hand sample: nothing to read
    store.write_trial("s1", _record(2, interrupted=True), [])
    store.begin_session("s2", "P02", "rig1", 2, 1, {})
    hand = [Sample(10**9 + i * 33_000_000, True, 0.5, 0.85 - 0.01 * i, None, None, None,
                   None, None) for i in range(30)]
    store.write_trial("s2", _record(1), hand)
    store.close()
    assert main(["--db", str(db), "--participant", "P01"]) == 2  # running: not let in
    line = _one_line(capsys)
    assert "'P01' has no session the inclusion rule (complete sessions only) lets in" in line
    assert "running (crashed?) after 2 of 8 trials; --min-trials N fits it" in line
    assert main(["--db", str(db), "--participant", "P01", "--min-trials", "1"]) == 2
    line = _one_line(capsys)
    assert "'P01'" in line and "no complete trial" in line
    assert main(["--db", str(db), "--participant", "P09", "--min-trials", "1"]) == 2
    assert "'P09' has no stored trials" in _one_line(capsys)


def test_a_session_of_three_options_is_not_fitted_and_says_why(tmp_path, capsys):
    db = tmp_path / "three.sqlite"
    with Store(db) as store:
        store.begin_session("s1", "P01", "rig1", 1, 0, {}, ("red", "blue", "green"))
        hand = [Sample(10**9 + i * 33_000_000, True, 0.5, 0.85 - 0.01 * i, None, None, None,
                       None, None) for i in range(30)]
        store.write_trial("s1", _record(1), hand)
    assert main(["--db", str(db), "--min-trials", "1"]) == 2
    assert _one_line(capsys) == (
        "nod fit: error: participant 'P01' ran options red, blue, green: the fit is defined "
        "for the paper's two options only (its simulated person and estimator are trained on "
        "two-option sessions; docs/multi-option.md)")


def test_fit_a_small_study_stores_and_exports_it(tmp_path, capsys):
    """Three simulated people, a tiny table: the JSON shape, the figures, the store, the CSV."""
    db = tmp_path / "study.sqlite"
    assert cohort.main(["--participants", "3", "--seed", "7", "--db", str(db), "--quiet",
                        "--workers", "1"]) == 0
    capsys.readouterr()
    out = tmp_path / "fit"
    args = ["--db", str(db), "--table", "24", "--predictive", "2", "--workers", "1",
            "--cache", str(tmp_path / "cache"), "--out", str(out), "--json"]
    assert main(args) == 0
    doc = json.loads(capsys.readouterr().out)
    rows = doc["participants"]
    assert [r["participant"] for r in rows] == ["P001", "P002", "P003"]
    names = set(doc["identifiable"]) | set(doc["not_identifiable"])
    assert {"speed", "preference_mean", "gaze_gain"} <= names
    for r in rows:
        assert set(r["parameters"]) == set(doc["identifiable"])  # never a non-identifiable one
        for v in r["parameters"].values():
            assert v["low"] <= v["estimate"] <= v["high"]
            if "probability" in v:  # a kind: its likelier value, its probability, its set
                assert v["estimate"] in v["set"] and 0 <= v["probability"] <= 1
        pred = r["predictive"]
        assert pred["sessions"] == 2 and sum(pred["simulated"].values()) == pytest.approx(1)
        assert len(pred["observed_press_s"]) >= 1
    for name in ("fit.json", "fit.csv", "fit_intervals.png", "fit_predictive.png"):
        assert (out / name).stat().st_size > 0
    store = Store(db)
    try:
        stored = read_fits(store)
    finally:
        store.close()
    expected = {(r["participant"], n) for r in rows for n in r["parameters"]}
    assert {(f.participant, f.parameter) for f in stored} == expected
    assert export_main(["--db", str(db), "--out", str(tmp_path / "csv")]) == 0
    probability = {(r["participant"], n): v.get("probability") for r in rows
                   for n, v in r["parameters"].items()}
    assert {(f.participant, f.parameter): f.probability for f in stored} == probability
    for r in rows:  # the out-of-prior check: its p beside every estimate, in the store too
        assert 0 < r["prior_check"]["p"] <= 1 and isinstance(r["prior_check"]["outside"], bool)
        assert {f.prior_p for f in stored if f.participant == r["participant"]} == (
            {r["prior_check"]["p"]} if r["parameters"] else set())
    exported = list(csv.DictReader((tmp_path / "csv" / "fits.csv").open()))
    assert len(exported) == len(expected)
    written = list(csv.DictReader((out / "fit.csv").open()))
    assert [r["probability"] for r in written] == [r["probability"] for r in exported]
    assert [r["prior_p"] for r in written] == [r["prior_p"] for r in exported]
    # A second fit (from the cached table) replaces the rows, never doubles them.
    assert main(args[:-1] + ["--participant", "P002"]) == 0
    assert "P002" in capsys.readouterr().out
    store = Store(db)
    try:
        assert len(read_fits(store)) == len(expected)
    finally:
        store.close()


def test_a_small_real_fit_puts_every_estimate_inside_its_interval_or_set(tmp_path):
    """A real table (40 people of the shipped cohort) and four real people: every parameter,
    reported or not, has its estimate inside its own interval, and each kind its likelier
    value inside its set, its probability beside it — as the JSON and the table print them."""
    import numpy as np

    from services.cohort.person import load_cohort_params
    from services.fit.pipeline import prepare
    from services.fit.report import fit_table, parameter_cell
    from services.fit.simulate import Population, simulate

    def run(fn, jobs):  # the engine, in this process
        return [fn(job) for job in jobs]

    pop = Population(load_cohort_params(None))
    prep = prepare(pop, 40, run, tmp_path)
    people = run(simulate, [(pop, 7 + i) for i in range(4)])
    fit = prep.estimator.predict(np.stack([p.summaries for p in people]))
    kinds = [j for j, n in enumerate(fit.names) if n in ("late_switcher", "contrarian")]
    assert len(kinds) == 2 and np.isfinite(fit.probability[:, kinds]).all()
    rows = []
    for i, person in enumerate(people):
        cells = {n: parameter_cell(fit.estimate[i, j], fit.low[i, j], fit.high[i, j],
                                   fit.probability[i, j]) for j, n in enumerate(fit.names)}
        for cell in cells.values():
            assert cell["low"] <= cell["estimate"] <= cell["high"]
            if "probability" in cell:
                assert cell["estimate"] in cell["set"]
                assert cell["estimate"] == (1 if cell["probability"] >= 0.5 else 0)
        rows.append({"participant": f"P{person.seed}", "trials": 8, "parameters": cells})
    table = fit_table({"identifiable": list(fit.names), "participants": rows,
                       "not_identifiable": {}})
    first = rows[0]["parameters"]["contrarian"]
    assert f"(p {first['probability']:.2f}) {{{', '.join(map(str, first['set']))}}}" in table


def test_a_small_real_recovery_gives_each_row_its_intervals_and_repeats(tmp_path, capsys):
    """`nod fit recovery --participants N --seed S --json` on a small table: each parameter's r
    with its bootstrap interval, its coverage with its Wilson interval, the out-of-prior
    check's share flagged; a rerun, the same; `--population FILE` plants other people.
    (100 table people: the fewest whose boosting is not a constant, so r exists.)"""
    from services.model.recovery import wilson

    n = 10
    args = ["recovery", "--participants", str(n), "--seed", "3", "--table", "100",
            "--workers", "1", "--cache", str(tmp_path / "cache"), "--json"]
    assert main(args) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["seed"] == 3 and doc["intervals"]["level"] == 0.95
    for row in doc["parameters"]:
        lo, hi = row["coverage_ci95"]
        assert (lo, hi) == pytest.approx(wilson(round(row["coverage"] * n), n), abs=1e-4)
        assert lo <= row["coverage"] <= hi
        r, (r_lo, r_hi) = row["correlation"], row["correlation_ci95"]
        if r is not None and r_lo is not None:
            assert -1 <= r_lo <= r <= r_hi <= 1
        assert isinstance(row["edge"], bool)
    reaction = next(row for row in doc["parameters"] if row["name"] == "reaction_s")
    assert reaction["correlation"] > 0.9 and reaction["correlation_ci95"][0] > 0.7  # real
    check = doc["prior_check"]
    assert check["n"] == n and 0 <= check["flagged"] <= n and doc["population"] == "the fit's prior"
    assert (check["rate_ci95"][0], check["rate_ci95"][1]) == pytest.approx(
        wilson(check["flagged"], n), abs=1e-4)
    assert main(args) == 0  # the tables now cached: a reviewer's rerun
    assert json.loads(capsys.readouterr().out)["parameters"] == doc["parameters"]
    assert main(args[:-1]) == 0
    table = capsys.readouterr().out
    assert "r 95 % CI" in table and "coverage 95 % CI" in table and "Wilson" in table
    assert "out-of-prior check:" in table
    # People of another population (the cohort's, hand speeds far outside the prior's), fitted
    # by the same estimator: their truth in the fit's parameters, the check flags them.
    other = tmp_path / "fast.toml"
    other.write_text("[participant]\nspeed = 0.9\n")
    assert main(args + ["--population", str(other)]) == 0
    planted = json.loads(capsys.readouterr().out)
    assert planted["population"] == str(other)
    assert {r["name"] for r in planted["parameters"]} == {r["name"] for r in doc["parameters"]}
    assert planted["prior_check"]["flagged"] >= 0.8 * n
    # Model recovery against that description: its sessions and the prior's told apart.
    assert main(args + ["--versus", str(other)]) == 0
    versus = json.loads(capsys.readouterr().out)["versus"]
    assert versus["versus"] == str(other) and versus["sessions"] == 2 * n
    assert versus["accuracy"] == pytest.approx((versus["first"] + versus["second"]) / 2)
    assert versus["accuracy"] >= 0.8
    assert main(args[:-1] + ["--versus", str(other)]) == 0
    assert f"model recovery (the prior or {other})" in capsys.readouterr().out


def test_a_bad_prior_file_is_one_line(tmp_path, capsys):
    """`--prior FILE` is read before anything is simulated; a wrong one ends in one line."""
    db = tmp_path / "empty.sqlite"
    Store(db).close()
    bad = tmp_path / "prior.toml"
    bad.write_text("[traits.speed]\nlow = 0.4\nhigh = 0.2\n")
    assert main(["--db", str(db), "--prior", str(bad)]) == 2
    assert "traits.speed: needs finite low <= high" in _one_line(capsys)
    assert main(["recovery", "--participants", "2", "--prior", str(tmp_path / "nope.toml")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "config file not found" in err
    assert main(["recovery", "--participants", "2", "--population", str(bad)]) == 2
    assert "traits.speed: needs finite low <= high" in capsys.readouterr().err


def test_recovery_by_length_reads_each_length_and_its_eighth_is_the_whole_fit(tmp_path, capsys):
    """`nod fit recovery --by-length`: r and coverage after 1..8 trials; after 8 the numbers of
    `nod fit recovery` itself (the same estimator, the same people)."""
    n = 10
    args = ["recovery", "--participants", str(n), "--seed", "3", "--table", "100",
            "--workers", "1", "--cache", str(tmp_path / "cache"), "--json"]
    assert main(args + ["--by-length"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [row["trials"] for row in doc["lengths"]] == list(range(1, 9))
    assert "one estimator per session length" in doc["method"]
    for length in doc["lengths"]:
        for row in length["parameters"]:
            assert row["n"] == n and 0 <= row["coverage"] <= 1 and row["mean_width"] >= 0
    eighth = {r["name"]: r for r in doc["lengths"][-1]["parameters"]}
    assert eighth["reaction_s"]["correlation"] > 0.9
    assert main(args) == 0
    whole = json.loads(capsys.readouterr().out)["parameters"]
    for row in whole:
        for key in ("correlation", "coverage", "bias"):
            assert eighth[row["name"]][key] == row[key], (row["name"], key)
    assert main(args[:-1] + ["--by-length"]) == 0
    text = capsys.readouterr().out
    assert "k=1 r/cov" in text and "k=8 r/cov" in text and "reaction_s" in text
