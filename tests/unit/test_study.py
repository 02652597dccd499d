"""The study analysis (Secs 7-8, Fig 8) on a realistic simulated cohort stored in SQLite."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy import stats

from services.analysis.multiplicity import adjust
from services.analysis.sessions import InclusionRule, scheduled_trials, select_sessions
from services.analysis.stuart_maxwell import stuart_maxwell
from services.analysis.study import (
    OUTCOMES,
    likert_test,
    load_study,
    phase_category,
    q3_test,
)
from services.model.closed_loop import OfflineTrial, run_offline_session
from services.model.params import NodConfig
from services.sim.cohort import offline_record
from services.store import QuestionnaireRecord, Sample, Store, TrialRecord

ROOT = Path(__file__).resolve().parents[2]
SEEDS = range(12)


def _simulate(seed: int) -> list[OfflineTrial]:
    return run_offline_session(NodConfig(), seed, cohort=True)


def _record(t: OfflineTrial, cfg: NodConfig) -> TrialRecord:
    return offline_record(t, cfg.protocol.trials[t.trial - 1], t.trial * 10**10)


@pytest.fixture(scope="module")
def cohort_db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """12 simulated participants, a timeout, a re-run, and three incomplete sessions.

    P02 is aborted before its last trial, P13 after 4 of 8 trials (its experiment phase is one
    trial), P14 is left running after 2 (a crash).
    """
    cfg = NodConfig()
    with ProcessPoolExecutor(max_workers=min(4, os.cpu_count() or 1)) as pool:
        sessions = list(pool.map(_simulate, SEEDS))
    path = tmp_path_factory.mktemp("study") / "study.db"
    store = Store(path)
    # P03's first attempt is superseded by a later session of the same participant.
    store.begin_session("old-P03", "P03", "sim", 99, 1, {})
    store.write_trial("old-P03", _record(sessions[0][0], cfg), [])
    store.finish_session("old-P03", 2, "aborted")
    for seed, trials in zip(SEEDS, sessions, strict=True):
        sid, pid = f"s{seed:02d}", f"P{seed + 1:02d}"
        store.begin_session(sid, pid, "sim", seed, 10 + seed, {"seed": seed})
        for t in trials:
            if pid == "P02" and t.trial == 8:
                break  # aborted before the last trial: trial 8 is missing
            rec = _record(t, cfg)
            if pid == "P01" and t.trial == 5:  # a timeout: no press, no outcome
                rec = replace(rec, human=None, outcome=None, end_reason="timeout")
            store.write_trial(sid, rec, [Sample(0, True, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)])
        store.finish_session(sid, 100 + seed, "aborted" if pid == "P02" else "complete")
    for pid, stop, status in (("P13", 4, "aborted"), ("P14", 2, "running")):
        store.begin_session(f"s-{pid}", pid, "sim", 0, 50, cfg.summary())
        for t in sessions[0][:stop]:
            store.write_trial(f"s-{pid}", _record(t, cfg), [])
        if status != "running":
            store.finish_session(f"s-{pid}", 60, status)
    rng = np.random.default_rng(7)
    answers = [
        QuestionnaireRecord(
            f"P{i + 1:02d}",
            *(int(v) for v in rng.integers(1, 11, size=2)),
            str(rng.choice(["Yes", "No", "Maybe"])),
            *(int(v) for v in rng.integers(1, 11, size=2)),
        )
        for i in range(10)
    ]
    store.write_questionnaires(answers, 0, "test")
    store.close()
    return path


@pytest.fixture(scope="module")
def doc(cohort_db: Path) -> dict:
    return load_study(str(cohort_db))


@pytest.fixture(scope="module")
def doc_min4(cohort_db: Path) -> dict:
    return load_study(str(cohort_db), InclusionRule(min_trials=4))


def _db_outcomes(path: Path) -> dict[str, dict[int, str | None]]:
    store = Store(path)
    try:
        parts = select_sessions(store).participants
    finally:
        store.close()
    return {p.participant: dict(p.outcomes) for p in parts}


def _reasons(doc: dict) -> dict[str, str]:
    return {e["session"]: e["reason"] for e in doc["excluded"]}


def test_only_complete_sessions_count_and_each_exclusion_says_why(doc: dict) -> None:
    assert doc["participants"] == 11 and "P02" not in doc["grid"]
    assert doc["inclusion"]["rule"] == "complete" and doc["inclusion"]["min_trials"] is None
    assert _reasons(doc) == {
        "old-P03": "aborted after 1 of 8 trials",
        "s01": "aborted after 7 of 8 trials",
        "s-P13": "aborted after 4 of 8 trials",
        "s-P14": "running (crashed?) after 2 of 8 trials",
    }
    p13 = next(e for e in doc["excluded"] if e["participant"] == "P13")
    assert p13 == {
        "session": "s-P13", "participant": "P13", "reason": "aborted after 4 of 8 trials",
        "status": "aborted", "trials_stored": 4, "trials_scored": 4, "trials_scheduled": 8,
    }
    assert [s["session"] for s in doc["sessions"] if s["participant"] == "P03"] == ["s02"]
    assert {"participant": "P01", "trial": 5, "reason": "timeout"} in doc["excluded_trials"]
    assert not any(e["participant"] in ("P02", "P13") for e in doc["excluded_trials"])
    assert doc["grid"]["P01"][4] is None
    # P02 answered the questionnaire, but its session is excluded: so are its answers.
    assert doc["questionnaire_excluded"] == ["P02"] and doc["questionnaire"]["n"] == 9


def test_min_trials_lets_the_aborted_session_in(doc_min4: dict) -> None:
    assert doc_min4["inclusion"]["rule"] == "min_trials"
    assert doc_min4["inclusion"]["min_trials"] == 4
    assert doc_min4["participants"] == 13
    assert doc_min4["grid"]["P13"] == [*doc_min4["grid"]["P13"][:4], None, None, None, None]
    assert {"participant": "P13", "trial": 6, "reason": "missing"} in doc_min4["excluded_trials"]
    assert {"participant": "P02", "trial": 8, "reason": "missing"} in doc_min4["excluded_trials"]
    # The case of the issue: P13's experiment category rests on its one experiment trial.
    assert doc_min4["phase_categories"]["P13"]["experiment"] == doc_min4["grid"]["P13"][3]
    assert sum(map(sum, doc_min4["contingency"]["table"])) == 13
    assert _reasons(doc_min4) == {
        "old-P03": "aborted after 1 of 8 trials: 1 scored trial(s), fewer than --min-trials 4",
        "s-P14": "running (crashed?) after 2 of 8 trials: 2 scored trial(s), fewer than "
        "--min-trials 4",
    }


def test_a_superseded_session_is_excluded_as_such(cohort_db: Path) -> None:
    doc = load_study(str(cohort_db), InclusionRule(min_trials=1))
    assert _reasons(doc)["old-P03"] == "superseded by the later session s02"
    assert doc["participants"] == 14


def test_json_carries_raw_and_holm_adjusted_p(doc: dict) -> None:
    tests = doc["stuart_maxwell"]
    assert doc["correction"] == "holm"
    family = doc["correction_family"]
    assert family == [name for name, t in tests.items() if "error" not in t]
    assert "control_vs_experiment" in family and len(family) >= 3
    raw = [tests[name]["p"] for name in family]
    assert [tests[name]["p_adjusted"] for name in family] == adjust(raw, "holm")
    m = len(family)
    first = min(family, key=lambda name: tests[name]["p"])
    assert tests[first]["p_adjusted"] == pytest.approx(min(1.0, m * tests[first]["p"]))
    assert all(tests[n]["p"] <= tests[n]["p_adjusted"] <= 1.0 for n in family)
    assert all("p_adjusted" not in t for t in tests.values() if "error" in t)


def test_bonferroni_and_no_correction(cohort_db: Path, doc: dict) -> None:
    family = doc["correction_family"]
    m = len(family)
    bonf = load_study(str(cohort_db), correction="bonferroni")
    none = load_study(str(cohort_db), correction="none")
    assert bonf["correction"] == "bonferroni" and none["correction"] == "none"
    for name in family:
        p = doc["stuart_maxwell"][name]["p"]
        assert bonf["stuart_maxwell"][name]["p_adjusted"] == pytest.approx(min(1.0, m * p))
        assert none["stuart_maxwell"][name]["p_adjusted"] == p
        assert doc["stuart_maxwell"][name]["p_adjusted"] <= bonf["stuart_maxwell"][name][
            "p_adjusted"
        ]


def test_frequencies_sum_to_participants_and_match_the_db(doc: dict, cohort_db: Path) -> None:
    outcomes = _db_outcomes(cohort_db)
    for trial in doc["trials"]:
        row = doc["frequencies"][str(trial)]
        assert sum(row[o] for o in OUTCOMES) + row["none"] == row["n"] == 11
        counts = Counter(o.get(trial) for o in outcomes.values())
        assert all(row[o] == counts[o] for o in OUTCOMES)
    assert doc["frequencies"]["5"]["none"] == 1 and doc["frequencies"]["8"]["none"] == 0


def test_contingency_margins_match_the_phase_categories(doc: dict) -> None:
    cats = doc["phase_categories"]
    table = np.array(doc["contingency"]["table"])
    control = Counter(c["control"] for c in cats.values())
    experiment = Counter(c["experiment"] for c in cats.values())
    assert table.sum(axis=1).tolist() == [control[o] for o in OUTCOMES]
    assert table.sum(axis=0).tolist() == [experiment[o] for o in OUTCOMES]
    assert doc["contingency"]["row_totals"] == table.sum(axis=1).tolist()
    assert table.sum() == 11  # every included participant has outcomes in both phases
    flows = {(f["from"], f["to"]): f["count"] for f in doc["flows"]}
    assert sum(flows.values()) == 11
    # The simulated cohort behaves like the paper's: dissensus first, consensus later.
    assert control["D"] + control["DH"] >= 9 and experiment["C"] + experiment["CH"] >= 9


def test_phase_categories_follow_the_rule(doc: dict, cohort_db: Path) -> None:
    for pid, outcomes in _db_outcomes(cohort_db).items():
        control = [outcomes.get(t) for t in (1, 2, 3)]
        assert doc["phase_categories"][pid]["control"] == phase_category(control)


def test_stuart_maxwell_is_the_library_test_on_the_same_tables(doc: dict, cohort_db: Path) -> None:
    main = doc["stuart_maxwell"]["control_vs_experiment"]
    ref = stuart_maxwell(doc["contingency"]["table"])
    assert main["statistic"] == pytest.approx(ref.statistic, rel=1e-12)
    assert main["p"] == pytest.approx(ref.p) and main["df"] == ref.df
    outcomes = _db_outcomes(cohort_db)
    for a, b in ((4, 5), (5, 6), (6, 7), (7, 8)):
        test = doc["stuart_maxwell"][f"trial_{a}_vs_{b}"]
        table = np.zeros((4, 4), dtype=int)
        for o in outcomes.values():
            if o.get(a) is not None and o.get(b) is not None:
                table[OUTCOMES.index(o[a]), OUTCOMES.index(o[b])] += 1
        assert test["table"] == table.tolist() and test["n"] == table.sum()
        try:
            res = stuart_maxwell(table)
        except ValueError as exc:
            assert test["error"] == str(exc)
        else:
            assert test["statistic"] == pytest.approx(res.statistic, rel=1e-12)


def test_questionnaire_statistics_are_scipys(doc: dict, cohort_db: Path) -> None:
    store = Store(cohort_db)
    answers = store.questionnaires()
    store.close()
    answers = [a for a in answers if a.participant != "P02"]  # its session is excluded
    q = doc["questionnaire"]
    assert q["n"] == 9
    for key in ("q1", "q2", "q4", "q5"):
        x = np.array([getattr(a, key) for a in answers], dtype=float)
        ref = stats.ttest_1samp(x, 5.5)
        assert q[key]["t"] == pytest.approx(ref.statistic) and q[key]["p"] == pytest.approx(
            ref.pvalue
        )
        assert q[key]["cohens_d"] == pytest.approx((x.mean() - 5.5) / x.std(ddof=1))
    counts = Counter(a.q3 for a in answers)
    ref = stats.chisquare([counts["Yes"], counts["No"], counts["Maybe"]])
    assert q["q3"]["chi2"] == pytest.approx(ref.statistic) and q["q3"]["df"] == 2
    assert q["q3"]["cramers_v"] == pytest.approx(np.sqrt(ref.statistic / (9 * 2)))
    assert doc["sessions_without_questionnaire"] == ["P11", "P12"]


def _nod(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "services.cli", "analyze", "study", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )


def _no_nan(name: str) -> None:
    raise AssertionError(f"non-JSON constant {name} in the output")


def test_cli_json_and_report(doc: dict, cohort_db: Path, tmp_path: Path) -> None:
    out = tmp_path / "report"
    res = _nod("--db", str(cohort_db), "--json", "--out", str(out))
    assert res.returncode == 0, res.stderr
    printed = json.loads(res.stdout, parse_constant=_no_nan)
    assert printed == json.loads(json.dumps(doc))  # every number of the library's document
    assert json.loads((out / "study.json").read_text()) == printed
    for name in ("8a_frequencies", "8b_flows", "8c_grid", "8d_contingency"):
        png = (out / f"fig{name}.png").read_bytes()
        assert png.startswith(b"\x89PNG") and len(png) > 5000
    md = (out / "report.md").read_text()
    assert md.count("](fig8") == 4
    main = doc["stuart_maxwell"]["control_vs_experiment"]
    assert f"{main['statistic']:.4f}" in md
    for key in ("q1", "q2", "q4", "q5"):
        assert f"{doc['questionnaire'][key]['t']:.4g}" in md
    assert f"{doc['questionnaire']['q3']['chi2']:.4f}" in md
    assert "P01 trial 5: timeout" in md
    assert "Inclusion: complete sessions only" in md
    assert "- P13 (session s-P13): aborted after 4 of 8 trials" in md
    assert "- P14 (session s-P14): running (crashed?) after 2 of 8 trials" in md
    assert "Holm over the family of 5 defined Stuart-Maxwell tests" in md
    assert "| p (raw) | p (Holm) |" in md
    for name, t in doc["stuart_maxwell"].items():  # each row: raw p, then the adjusted p
        label = name.replace("_", " ").replace("vs", "→").replace("trial ", "trials ")
        row = next(line for line in md.splitlines() if line.startswith(f"| {label} |"))
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert float(cells[4]) == pytest.approx(t["p"], rel=1e-3)
        assert float(cells[5]) == pytest.approx(t["p_adjusted"], rel=1e-3)
    terminal = _nod("--db", str(cohort_db)).stdout
    assert "excluded P13 (s-P13): aborted after 4 of 8 trials" in terminal
    assert "Holm p = " in terminal


def test_cli_min_trials_and_correction(doc_min4: dict, cohort_db: Path) -> None:
    res = _nod("--db", str(cohort_db), "--json", "--min-trials", "4")
    assert res.returncode == 0, res.stderr
    printed = json.loads(res.stdout, parse_constant=_no_nan)
    assert printed == json.loads(json.dumps(doc_min4))
    assert printed["correction"] == "holm" and "P13" in printed["grid"]
    res = _nod("--db", str(cohort_db), "--correction", "bonferroni")
    assert res.returncode == 0, res.stderr
    assert "adjusted by Bonferroni" in res.stdout and "Bonferroni p = " in res.stdout
    res = _nod("--db", str(cohort_db), "--min-trials", "0")
    assert res.returncode == 2 and res.stderr.count("\n") == 1
    res = _nod("--db", str(cohort_db), "--min-trials", "9")
    assert res.returncode == 2 and res.stderr.count("\n") == 1
    assert "no session passes the inclusion rule" in res.stderr


def test_cli_vector_formats_and_panel_letters(cohort_db: Path, tmp_path: Path) -> None:
    out = tmp_path / "paper"
    res = _nod("--db", str(cohort_db), "--out", str(out), "--format", "pdf,svg")
    assert res.returncode == 0, res.stderr
    assert "(pdf/svg)" in res.stdout
    for name, letter in (("8a_frequencies", "a"), ("8b_flows", "b"), ("8c_grid", "c"),
                         ("8d_contingency", "d")):
        assert (out / f"fig{name}.pdf").read_bytes().startswith(b"%PDF")
        svg = (out / f"fig{name}.svg").read_text()
        assert "<svg" in svg and not (out / f"fig{name}.png").exists()
        # SVG keeps text as glyph paths with the characters in comments: the panel letter is
        # there, as in the paper's Fig 8.
        assert f"({letter})" in svg
    res = _nod("--db", str(cohort_db), "--out", str(out), "--format", "jpg")
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "png, pdf, svg" in res.stderr


def test_cli_errors_are_one_line(tmp_path: Path) -> None:
    res = _nod("--db", str(tmp_path / "nope.db"))
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "no such database" in res.stderr
    Store(tmp_path / "empty.db").close()
    res = _nod("--db", str(tmp_path / "empty.db"))
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "nod run" in res.stderr


def test_phase_category_examples() -> None:
    assert phase_category(["D", "D", "C"]) == "D"
    assert phase_category(["D", "C", "CH"]) == "CH"  # three-way tie: the later trial
    assert phase_category(["C", "C", "CH", "CH", "D"]) == "CH"
    assert phase_category(["CH", "C", "C", "CH", None]) == "CH"
    assert phase_category([None, "DH", None]) == "DH"
    assert phase_category([None, None]) is None


@given(st.lists(st.sampled_from([*OUTCOMES, None]), min_size=1, max_size=8))
def test_phase_category_is_a_mode_and_ties_go_late(outcomes: list[str | None]) -> None:
    got = phase_category(outcomes)
    counts = Counter(o for o in outcomes if o is not None)
    if not counts:
        assert got is None
        return
    top = max(counts.values())
    assert counts[got] == top
    last = max(i for i, o in enumerate(outcomes) if o is not None and counts[o] == top)
    assert outcomes[last] == got


def test_degenerate_questionnaire_tests_explain_themselves() -> None:
    assert "at least 2" in likert_test([7])["error"]
    assert "zero spread" in likert_test([6, 6, 6])["error"]
    assert q3_test([])["error"] == "no Q3 answers"
    with pytest.raises(ValueError, match="Yes, No, Maybe"):
        q3_test(["Yes", "Perhaps"])
    doc = q3_test(["Yes"] * 6)
    assert doc["chi2"] == pytest.approx(12.0) and doc["cohens_w"] == pytest.approx(np.sqrt(2.0))


def test_an_interrupted_trial_is_excluded_trial_wise_and_the_session_counts(
    tmp_path: Path,
) -> None:
    cfg = NodConfig()
    trials = _simulate(3)
    store = Store(tmp_path / "s.db")
    store.begin_session("s1", "P01", "sim", 3, 0, cfg.summary())
    for t in trials:
        rec = _record(t, cfg)
        store.write_trial("s1", replace(rec, interrupted=True) if t.trial == 6 else rec, [])
    store.finish_session("s1", 1)
    store.close()
    doc = load_study(str(tmp_path / "s.db"))
    assert doc["participants"] == 1 and doc["excluded"] == []
    assert doc["excluded_trials"] == [{"participant": "P01", "trial": 6, "reason": "interrupted"}]
    assert doc["grid"]["P01"][5] is None
    assert any("trial 6 was interrupted" in n for n in doc["notes"])
    # Under --min-trials, an interrupted trial is not a scored one: 7 of 8 are.
    assert load_study(str(tmp_path / "s.db"), InclusionRule(7))["participants"] == 1
    with pytest.raises(ValueError, match="no session passes the inclusion rule"):
        load_study(str(tmp_path / "s.db"), InclusionRule(8))


def test_the_schedule_comes_from_the_stored_protocol() -> None:
    assert scheduled_trials(json.dumps(NodConfig().summary(), default=str)) == 8
    assert scheduled_trials(json.dumps({"protocol": {"trials": [{}, {}, {}]}})) == 3
    assert scheduled_trials("{}") == scheduled_trials(None) == scheduled_trials("not json") == 8


def _plain(n: int) -> TrialRecord:
    """A stored trial, both pressed red: C."""
    return TrialRecord(n, "dissensus" if n <= 3 else "consensus", None if n <= 3 else "red",
                       "neutral", 0.0, 0.0, 1, 2, "red", "red", "C", 0, 0, 10, 2, "pressed")


def test_a_complete_session_missing_a_scheduled_trial_is_excluded(tmp_path: Path) -> None:
    # The default rule: status complete *and* every scheduled trial stored. A session marked
    # complete with a scheduled trial missing (from the SPEC's 8, or from its own protocol's
    # longer schedule) is left out and says why; only the one with every trial counts.
    cfg = NodConfig().summary()
    ten = {"protocol": {"trials": [{}] * 10, "control_labels": "agreement"}}
    store = Store(tmp_path / "s.db")
    for i, (pid, config, numbers) in enumerate((
        ("P01", cfg, range(1, 9)),
        ("P02", cfg, [n for n in range(1, 9) if n != 5]),  # trial 5 never stored
        ("P03", cfg, range(2, 9)),  # the first one missing
        ("P04", ten, range(1, 9)),  # 8 stored of its 10
    )):
        store.begin_session(f"s-{pid}", pid, "sim", i, i, config)
        for n in numbers:
            store.write_trial(f"s-{pid}", _plain(n), [])
        store.finish_session(f"s-{pid}", 100 + i)  # marked complete
    try:
        selection = select_sessions(store)
    finally:
        store.close()
    assert [p.participant for p in selection.participants] == ["P01"]
    assert {e.session: e.reason for e in selection.excluded} == {
        "s-P02": "complete but only 7 of 8 trials stored",
        "s-P03": "complete but only 7 of 8 trials stored",
        "s-P04": "complete but only 8 of 10 trials stored",
    }
    doc = load_study(str(tmp_path / "s.db"))
    assert doc["participants"] == 1 and sorted(_reasons(doc)) == ["s-P02", "s-P03", "s-P04"]
