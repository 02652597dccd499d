"""nod cohort --policy: the paper's robot is today's cohort; an adaptive one is stored per trial."""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import pytest

from services.cohort.person import load_cohort_params
from services.cohort.policy_file import make_policy, read_policy_file
from services.cohort.policy_table import build_table, table_from_json, table_to_json
from services.compute.engine import Engine
from services.model.decision import DecisionParams
from services.model.policy import KINDS, PolicySettings, paper_settings
from services.model.schedule import default_schedule
from services.sim.cohort import StoredPolicy, run_cohort
from services.sim.cohort import main as cohort_main
from services.store import Store
from services.store.policies import read_policies


class Here(Engine):
    """The sessions in this process, in order."""

    def __init__(self) -> None:
        super().__init__(client=None, where="in process")  # type: ignore[arg-type]

    def imap(self, fn: Callable, items: Sequence, chunk: int | None = None) -> Iterator:
        return map(fn, items)


def stored(db) -> list[Any]:
    store = Store(db)
    try:
        out = []
        for s in store.sessions():
            for _, t in store.trials(s["session"]):
                out.append((t, store.samples(s["session"], t.trial)))
        return out
    finally:
        store.close()


def test_the_paper_policy_is_todays_cohort_trial_for_trial(tmp_path):
    cfg = load_cohort_params(None)
    run_cohort(Here(), 3, 5, tmp_path / "today.sqlite", cfg, show=False)
    pf = read_policy_file("paper")
    run_cohort(Here(), 3, 5, tmp_path / "paper.sqlite", cfg, show=False,
               policy=StoredPolicy(pf, make_policy(pf, cfg)))
    today, paper = stored(tmp_path / "today.sqlite"), stored(tmp_path / "paper.sqlite")
    assert len(today) == 24 and paper == today  # trials and samples
    store = Store(tmp_path / "paper.sqlite")
    try:
        policies = read_policies(store)
    finally:
        store.close()
    assert sorted(policies) == ["cohort-5", "cohort-6", "cohort-7"]
    specs = default_schedule()
    for p in policies.values():
        assert (p.policy, p.sha256) == ("paper", pf.sha256)
        assert p.kind in KINDS
        assert p.trials == {s.index: paper_settings(cfg.decision, s) for s in specs}


def test_an_adaptive_cohort_stores_its_policy_and_settings(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("NOD_POLICY_CACHE", str(tmp_path / "cache"))
    policy = tmp_path / "bold.toml"
    policy.write_text('kind = "adaptive"\ngaze_levels = ["neutral", "extreme"]\nb_stars = [6.0]\n'
                      'u_rs = [2.24]\ntable_people = 4\ntable_seed = 900000001\n')
    db = tmp_path / "a.sqlite"
    assert cohort_main(["--participants", "3", "--seed", "1", "--db", str(db), "--quiet",
                        "--workers", "1", "--no-samples", "--policy", str(policy)]) == 0
    assert len(list((tmp_path / "cache").glob("*.json"))) == 1  # the table, kept
    store = Store(db)
    try:
        policies = read_policies(store)
        cfg = load_cohort_params(None)
        for p in policies.values():
            assert (p.policy, p.sha256) == ("bold", hashlib.sha256(policy.read_bytes()).hexdigest())
            trials = {t.trial: t for _, t in store.trials(p.session)}
            for i, s in p.trials.items():
                assert cfg.policy.contains(s) and trials[i].gaze_level == s.gaze_level
                if i <= 3:  # the control trials are the paper's
                    assert s == paper_settings(cfg.decision, default_schedule()[i - 1])
                else:
                    assert s.b_star == 6.0 and s.gaze_level in ("neutral", "extreme")
    finally:
        store.close()


def test_policy_files_are_refused_in_one_line(tmp_path):
    bad = tmp_path / "p.toml"
    for text, match in (('kind = "bold"\n', "kind"), ('kind = "adaptive"\n', "needs"),
                        ("kind = [", "not TOML")):
        bad.write_text(text)
        with pytest.raises(ValueError, match=match) as err:
            read_policy_file(str(bad))
        assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="no-such"):
        read_policy_file(str(tmp_path / "no-such.toml"))
    outside = tmp_path / "wide.toml"
    outside.write_text('kind = "adaptive"\ngaze_levels = ["extreme"]\nb_stars = [9.0]\n'
                       'u_rs = [2.24]\ntable_people = 1\ntable_seed = 1\n')
    with pytest.raises(ValueError, match="outside"):
        make_policy(read_policy_file(str(outside)), load_cohort_params(None))


def test_a_table_counts_each_person_once_and_survives_json():
    cfg = load_cohort_params(None)
    a, b = PolicySettings(4.54, "neutral", 2.24), PolicySettings(6.0, "extreme", 2.24)
    table = build_table(cfg, (a, b), 6, 900000001)
    assert sum(table.prior.values()) == 6  # each person once
    control = paper_settings(DecisionParams(), default_schedule()[0])
    assert sum(c.n for c in table.cells[(control, 1, 0)].values()) == 6
    for t in (4, 5, 6, 7, 8):  # each consensus trial: one candidate per person
        cells = [c for (s, i, _), by_kind in table.cells.items() if i == t
                 for c in by_kind.values()]
        assert sum(c.n for c in cells) == 6
    cued = {key[2] for key in table.cells if key[0] == b and key[1] == 6}
    assert cued and cued <= {0, 1, 2}  # trials 4 and 5 each drew a (neutral) or b (extreme)
    assert table_from_json(table_to_json(table)) == table


def test_a_policy_built_on_other_people(tmp_path, monkeypatch):
    """--policy-params: the table is simulated from those people, not the cohort's."""
    monkeypatch.setenv("NOD_POLICY_CACHE", str(tmp_path / "cache"))
    policy = tmp_path / "small.toml"
    policy.write_text('kind = "adaptive"\ngaze_levels = ["neutral", "extreme"]\nb_stars = [4.54]\n'
                      'u_rs = [2.24]\ntable_people = 3\ntable_seed = 900000001\n')
    fitted, moved = tmp_path / "fitted.toml", tmp_path / "moved.toml"
    fitted.write_text("")
    moved.write_text("[participant]\ncontrarian_share = 0.9\n")
    common = ["--participants", "2", "--quiet", "--workers", "1", "--no-samples", "--policy",
              str(policy)]
    assert cohort_main([*common, "--db", str(tmp_path / "a.sqlite"), "--params", str(moved),
                        "--policy-params", str(fitted)]) == 0
    assert cohort_main([*common, "--db", str(tmp_path / "b.sqlite")]) == 0  # the fitted people
    assert len(list((tmp_path / "cache").glob("*.json"))) == 1  # one table: the fitted people's
    assert cohort_main([*common, "--db", str(tmp_path / "c.sqlite"), "--params", str(moved)]) == 0
    assert len(list((tmp_path / "cache").glob("*.json"))) == 2  # built on the moved people
