"""nod analyze policies: two cohorts' C and C + CH on O, per trial and kind, and the power."""

from __future__ import annotations

import json

import numpy as np
import pytest

from services.analysis.cli import main as analyze_main
from services.analysis.policies import compare, estimate, load_condition, power
from services.cohort.person import load_cohort_params
from services.cohort.policy_file import PolicyFile, read_policy_file
from services.model.policy import KINDS, AdaptivePolicy, OutcomeTable, PaperPolicy, PolicySettings
from services.sim.cohort import StoredPolicy, run_cohort
from services.store import Store
from tests.unit.test_cohort_policy import Here


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("policies")
    cfg = load_cohort_params(None)
    neutral = PolicySettings(6.0, "neutral", 2.24)
    bold = StoredPolicy(PolicyFile("neutral", "ab" * 32, {"kind": "adaptive"}),
                        AdaptivePolicy(OutcomeTable((neutral,), {k: 1 for k in KINDS})))
    paper = StoredPolicy(read_policy_file("paper"), PaperPolicy())
    for name, policy in (("paper", paper), ("neutral", bold)):
        run_cohort(Here(), 12, 1, tmp / f"{name}.sqlite", cfg, record=False, show=False,
                   policy=policy)
    return tmp / "paper.sqlite", tmp / "neutral.sqlite"


def test_the_shares_are_the_stores_counts(stores):
    paper, other = (load_condition(p) for p in stores)
    assert (paper.policy, other.policy, len(paper.people)) == ("paper", "neutral", 12)
    doc = compare(paper, other, reps=200, sizes=(5,), runs=50)
    store = Store(stores[0])
    try:
        c4 = [t.outcome == "C" and t.human == t.option == t.robot
              for s in store.sessions() for _, t in store.trials(s["session"]) if t.trial == 4]
    finally:
        store.close()
    assert doc["per_trial"]["4"]["c"]["paper"] == pytest.approx(sum(c4) / 12)
    e = doc["trials_4_8"]["c"]
    assert e["diff"] == pytest.approx(e["adaptive"] - e["paper"])
    assert e["diff_ci"][0] <= e["diff"] <= e["diff_ci"][1]
    assert doc["paired"] and e["diff_paired_ci"][0] <= e["diff"] <= e["diff_paired_ci"][1]
    kinds = {p.kind for p in paper.people}
    assert set(doc["per_kind"]) == kinds and kinds <= set(KINDS)


def test_the_command_prints_tables_and_json(stores, capsys):
    assert analyze_main(["policies", str(stores[0]), str(stores[1]), "--bootstrap", "200",
                         "--runs", "20", "--participants", "5,10"]) == 0
    out = capsys.readouterr().out
    assert "**trials 4–8**" in out and "| 10 |" in out
    assert analyze_main(["policies", *map(str, stores), "--json", "--bootstrap", "200",
                         "--runs", "20"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [p["n_per_robot"] for p in doc["power"]] == [20, 40, 60]


def test_power_finds_a_real_difference_and_not_a_null_one():
    rng = np.random.default_rng(3)
    a = rng.uniform(0.3, 0.7, 400)
    assert power(a, a + 0.3, 20, rng, 200, 0.05)["power"] > 0.95
    assert power(a, a.copy(), 20, rng, 400, 0.05)["power"] < 0.1
    e = estimate(a, a + 0.1, rng, 500, paired=True)
    assert e["diff"] == pytest.approx(0.1) and e["diff_ci"][0] > 0
    assert e["diff_paired_ci"] == pytest.approx([0.1, 0.1])  # every pair differs by 0.1
