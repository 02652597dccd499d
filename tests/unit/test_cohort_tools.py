"""nod cohort (the fitted person by default), cohort outcome shares, and the power analysis."""

from __future__ import annotations

import json
import math

import pytest

from services.analysis.power import TESTS, p_values, power, wilson
from services.cohort.outcomes import CATEGORIES, load_shares, shares, tvd
from services.cohort.person import FIG8A, FITTED_TRAITS, load_cohort_params
from services.model.closed_loop import run_offline_session
from services.sim.cohort import main as cohort_main
from services.store import Store


def test_nod_cohort_stores_a_study_that_the_tools_read(tmp_path, capsys):
    db = tmp_path / "c.sqlite"
    assert cohort_main(["--participants", "4", "--seed", "3", "--db", str(db), "--quiet",
                        "--workers", "1"]) == 0
    assert "4 simulated participants (32 trials)" in capsys.readouterr().out
    # The same cohort from the shipped fitted traits given as a file: the default is the fit.
    fitted = tmp_path / "fitted.toml"
    fitted.write_text(FITTED_TRAITS.read_text())
    again = tmp_path / "again.sqlite"
    assert cohort_main(["--participants", "4", "--seed", "3", "--db", str(again), "--quiet",
                        "--workers", "1", "--no-samples", "--params", str(fitted)]) == 0
    store = Store(db)
    try:
        sessions = store.sessions()
        assert [s["participant"] for s in sessions] == ["P001", "P002", "P003", "P004"]
        assert {s["rig"] for s in sessions} == {"offline"} and {s["status"] for s in sessions} == {
            "complete"
        }
        first = sessions[0]["session"]
        trials = [t for _, t in store.trials(first)]
        assert [t.trial for t in trials] == list(range(1, 9))
        direct = run_offline_session(load_cohort_params(None), 3, cohort=True)
        assert [t.outcome for t in trials] == [t.outcome for t in direct]  # the same model
        samples = store.samples(first, 4)
        assert len(samples) > 20 and all(math.isfinite(s.z_r) for s in samples)
        other = Store(again)
        try:
            assert [[t.outcome for _, t in other.trials(x["session"])] for x in other.sessions()
                    ] == [[t.outcome for _, t in store.trials(x["session"])] for x in sessions]
        finally:
            other.close()
    finally:
        store.close()
    # The same seeds into the same store: one line, before anything is simulated or written.
    capsys.readouterr()
    assert cohort_main(["--participants", "6", "--seed", "1", "--db", str(db), "--quiet",
                        "--workers", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "cohort-3" in err and "another --seed" in err, err
    store = Store(db)
    try:
        assert len(store.sessions()) == 4  # nothing half-written
    finally:
        store.close()


def test_tvd_and_shares():
    a = {"C": 0.5, "CH": 0.5, "D": 0.0, "DH": 0.0, "none": 0.0}
    b = {"C": 0.0, "CH": 0.5, "D": 0.5, "DH": 0.0, "none": 0.0}
    assert tvd(a, a) == 0.0 and tvd(a, b) == pytest.approx(0.5)
    got = shares([["C", None], ["D", "CH"]])
    assert got[1]["C"] == 0.5 and got[2]["none"] == 0.5
    assert all(abs(sum(v.values()) - 1) < 1e-12 for v in got.values())
    assert set(got[1]) == set(CATEGORIES)


def test_the_paper_target_loads_and_adds_up():
    target = load_shares(FIG8A.read_text(), "Fig 8a")
    assert sorted(target) == list(range(1, 9))
    assert target[8]["C"] == pytest.approx(0.8627) and target[1]["D"] == pytest.approx(0.7059)
    with pytest.raises(ValueError, match="add up"):
        load_shares(json.dumps({"trials": {"1": {"C": 0.7}}}), "bad.json")


def test_power_grows_with_n_on_a_population_with_a_real_effect():
    # A population where the control phase is D and the experiment phase mostly C: the
    # control-vs-experiment shift is large, so power rises with N and the intervals hold it.
    pop = [["D", "D", "D", "C", "C", "C", "C", "C"]] * 70 + [["D"] * 8] * 30
    # (Power now takes a list of populations and reports each correction: Holm and none.)
    doc = power([pop], [6, 30], runs=60, seed=2)
    small, large = (r["power"]["holm"]["control_vs_experiment"] for r in doc)
    assert large >= small and large > 0.9
    lo, hi = doc[1]["ci95"]["holm"]["control_vs_experiment"]
    assert lo <= large <= hi
    assert set(doc[0]["power"]["holm"]) == set(TESTS)


def test_no_effect_no_power():
    pop = [["D"] * 8] * 50
    p = p_values(pop[:20])
    assert all(math.isnan(v) for v in p.values())  # untestable: never "significant"
    result = power([pop], [20], runs=10)[0]["power"]
    assert all(v == 0 for corr in ("holm", "none") for v in result[corr].values())


def test_wilson_interval():
    lo, hi = wilson(50, 100)
    assert lo < 0.5 < hi and hi - lo == pytest.approx(0.19, abs=0.01)
    assert wilson(0, 10)[0] == 0.0 and wilson(10, 10)[1] == 1.0
