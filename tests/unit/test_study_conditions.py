"""Robot policies as conditions between subjects in a study file (issue 36): one per
participant, counterbalanced over the roster's orders or seeded at random, stored beside the
order, passed to the session as `--policy`, shown by `next` and `status`; a study file without
them is what it always was; a file whose conditions do not hold together is one line
(services/study/conditions.py, studyfile.py, cli.py)."""

from __future__ import annotations

import json
import re
import tomllib
from collections import Counter
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.counterbalance import latin_block, position_counts, roster_orders
from services.model.protocol import default_schedule
from services.model.schedule import OptionsSchedule
from services.store import Store, TrialRecord
from services.store.participants import record_consent, record_order
from services.store.policies import begin_policy
from services.study import cli
from services.study.conditions import (
    PolicyConditions,
    allocate,
    counterbalanced,
    identity,
    randomised,
)
from services.study.studyfile import StudyError, dump, load, make_study, write
from tests.refusals import refused_in_one_line

TWO = PolicyConditions((("paper", "paper"), ("adaptive", "adaptive")))
PAPER_FILE = 'kind = "paper"\n'  # a policy file: the paper's robot under another name


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def test_round_trip_with_policy_conditions_files_relative_to_the_study(tmp_path):
    (tmp_path / "policies").mkdir()
    tuned = tmp_path / "policies" / "tuned.toml"
    tuned.write_text(PAPER_FILE)
    pc = PolicyConditions((("paper", "paper"), ("tuned", str(tuned))), "counterbalanced")
    study = make_study("pilot", default_schedule(), 20, seed=3, policies=pc)
    (tmp_path / "studies").mkdir()
    path = tmp_path / "studies" / "pilot.toml"
    write(study, path)
    data = tomllib.loads(path.read_text())
    assert data["conditions"]["policies"] == {"paper": "paper", "tuned": "../policies/tuned.toml"}
    assert data["conditions"]["assignment"] == "counterbalanced"
    assert [p["condition"] for p in data["participants"]] == [
        e.condition for e in study.participants]
    back = load(path)
    assert back == study
    assert back.policy_arg(back.participants[0]) in ("paper", str(tuned))
    assert Counter(e.condition for e in back.participants) == {"paper": 10, "tuned": 10}


def test_the_paper_studys_two_conditions_cross_its_orders():
    """Two conditions over the paper's roster: every pair of slots (a rotation and its colour
    reversal) holds both, every block splits 5/5, and over two blocks each condition runs the
    whole Latin square: each order once, each colour O 10 times at every consensus trial."""
    study = make_study("s", default_schedule(), 40, seed=7, policies=TWO)
    people = study.participants
    for a, b in zip(people[::2], people[1::2], strict=True):
        assert {a.condition, b.condition} == {"paper", "adaptive"}
    square = sorted(latin_block(study.counterbalance.base))
    for start in (0, 20):
        for name in TWO.names:
            orders = [e.order for e in people[start:start + 20] if e.condition == name]
            assert sorted(orders) == square
            assert position_counts(orders) == [(5, 5)] * 5
    assert [e.order for e in people] == roster_orders(study.counterbalance.base, 40, 7)  # as ever


@settings(max_examples=60, deadline=None)
@given(k=st.integers(1, 4), n_options=st.integers(2, 3), n=st.integers(1, 4),
       seed=st.integers(0, 2**31 - 1), data=st.data())
def test_counterbalanced_conditions_meet_every_order_once_over_k_blocks(
        k, n_options, n, seed, data):
    names = ("red", "blue", "green")[:n_options]
    base = data.draw(st.lists(st.sampled_from(names), min_size=n, max_size=n))
    block = n * n_options
    orders = roster_orders(base, 2 * k * block, seed, names)
    picks = counterbalanced(base, orders, names, k)
    for start in range(0, len(orders), k * block):  # K blocks: each (order, condition) once
        pairs = Counter(zip(map(tuple, orders[start:start + k * block]),
                            picks[start:start + k * block], strict=True))
        assert pairs == Counter((o, c) for o in latin_block(base, names) for c in range(k))
    for start in range(0, len(orders), block):  # each block as even as it can be
        per = Counter(picks[start:start + block])
        assert max(per.values()) - min(per.get(c, 0) for c in range(k)) <= 1
    if n_options % k == 0:  # K divides N_o: every group of relabellings holds every condition
        for start in range(0, len(orders), n_options):
            assert Counter(picks[start:start + n_options]) == {c: n_options // k
                                                               for c in range(k)}


def test_random_assignment_is_the_seeds_draw():
    pc = PolicyConditions(TWO.policies, "random")
    a = make_study("s", default_schedule(), 30, seed=5, policies=pc)
    b = make_study("s", default_schedule(), 30, seed=5, policies=pc)
    c = make_study("s", default_schedule(), 30, seed=6, policies=pc)
    assert [e.condition for e in a.participants] == [e.condition for e in b.participants]
    assert [e.condition for e in a.participants] != [e.condition for e in c.participants]
    assert [e.condition for e in a.participants] == [
        TWO.names[i] for i in randomised(30, 2, 5)]
    assert [e.order for e in a.participants] == [e.order for e in
                                                 make_study("s", default_schedule(), 30,
                                                            seed=5).participants]
    assert randomised(60, 3, 1)[:30] == randomised(30, 3, 1)  # a slot's draw never moves


def test_a_study_file_without_policies_is_what_it_always_was(tmp_path, capsys):
    study = make_study("s", default_schedule(), 4, seed=2)
    path, db = tmp_path / "s.toml", tmp_path / "s.sqlite"
    write(study, path)
    text = path.read_text()
    assert "policies" not in text and "condition =" not in text and "assignment" not in text
    assert study.policy_conditions is None
    assert all(e.condition is None and study.policy_arg(e) is None for e in study.participants)
    store = Store(db)
    record_consent(store, "P01", True, 1, {})
    store.close()
    assert cli.main(["start", str(path), "--db", str(db), "--dry-run", "--", "--policy",
                     "adaptive"]) == 0  # the operator's own flag passes through, as it did
    out = capsys.readouterr().out
    assert out.count("--policy") == 1 and "condition" not in out
    assert cli.main(["status", str(path), "--db", str(db), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "conditions" not in doc and "condition" not in doc["participants"][0]
    assert cli.main(["status", str(path), "--db", str(db)]) == 0
    assert "condition" not in capsys.readouterr().out


def _edited(tmp_path: Path, old: str, new: str, policies: PolicyConditions | None = TWO,
            count: int = 1) -> Path:
    study = make_study("s", default_schedule(), 4, seed=2, policies=policies)
    path = tmp_path / "s.toml"
    text = dump(study, path)
    assert re.search(old, text), old
    path.write_text(re.sub(old, new, text, count=count))
    return path


POLICIES = r'policies = \{ paper = "paper", adaptive = "adaptive" \}'


@pytest.mark.parametrize(
    ("old", "new", "policies", "message"),
    [
        (POLICIES, POLICIES.replace("\\", "") + "\npolicy = 1", TWO,
         r"\[conditions\] has unknown key\(s\) \['policy'\]"),
        (r"gaze_levels = .*", r'\g<0>\nassignment = "random"', None,
         "assignment without policies"),
        (POLICIES, "policies = {}", TWO, r"\[conditions\] policies is empty"),
        (POLICIES, 'policies = { paper = "paper", tuned = "tuned.toml" }', TWO,
         r"policies.tuned: no policy file .*tuned.toml \(a path relative to the study file"),
        (POLICIES, 'policies = { paper = "paper", odd = "odd.toml" }', TWO,
         r"policies.odd: --policy .*odd.toml: needs kind"),
        (POLICIES, 'policies = ["paper", "adaptive"]', TWO,
         "policies must be a table of condition = policy"),
        (r'assignment = "counterbalanced"', 'assignment = "alternate"', TWO,
         r"assignment must be one of \('counterbalanced', 'random'\), got 'alternate'"),
        (r'condition = "\w+"', 'condition = "placebo"', TWO,
         r"participant 'P01' \(slot 1\): condition must be one of \['paper', 'adaptive'\], "
         "got 'placebo'"),
        (r'condition = "\w+"\n', "", TWO,
         r"participant 'P01' \(slot 1\): condition must be one of .* got none"),
        (r'order = (.*)\n', 'order = \\1\ncondition = "paper"\n', None,
         r"participant 'P01' \(slot 1\) has a condition, but \[conditions\] names no policies"),
        (r'condition = "paper"', 'condition = "adaptive"', TWO,
         r"condition 'adaptive', but the counterbalanced allocation gives 'paper'; .*"
         'method = "declared"'),
        (r'seed = 2\n', "", PolicyConditions(TWO.policies, "random"),
         r'assignment = "random" needs \[counterbalance\] seed'),
    ],
)
def test_broken_policy_conditions_are_one_line(tmp_path, old, new, policies, message):
    (tmp_path / "odd.toml").write_text('name = "no kind"\n')
    refused_in_one_line(load, _edited(tmp_path, old, new, policies), StudyError, message)


def test_conditions_need_the_papers_two_options(tmp_path):
    with pytest.raises(StudyError, match="two-option table only"):
        make_study("s", OptionsSchedule.default(3), 3, seed=1, policies=TWO)


def test_a_replacement_keeps_the_withdrawn_slots_condition_in_a_declared_file(tmp_path, capsys):
    """The existing rule for a participant who withdrew: a new id with the withdrawn slot's
    order, in a declared file; their condition comes with it, and so does their --policy."""
    study = make_study("s", default_schedule(), 4, seed=2, policies=TWO)
    gone = study.participants[1]
    path, db = tmp_path / "s.toml", tmp_path / "s.sqlite"
    text = dump(study, path).replace('method = "latin-square"', 'method = "declared"')
    text += (f'\n[[participants]]\nid = "P02b"\nslot = 5\norder = {json.dumps(list(gone.order))}'
             f'\ncondition = "{gone.condition}"\n')
    path.write_text(text)
    back = load(path)
    assert back.participants[-1].condition == gone.condition
    store = Store(db)
    record_consent(store, "P02b", True, 1, {})
    store.close()
    assert cli.main(["start", str(path), "--db", str(db), "--participant", "P02b",
                     "--dry-run"]) == 0
    assert f"--policy {gone.condition}" in capsys.readouterr().out


def test_init_writes_conditions_and_refuses_a_bad_one(tmp_path, capsys):
    (tmp_path / "tuned.toml").write_text(PAPER_FILE)
    path = tmp_path / "s.toml"
    assert cli.main(["init", str(path), "--participants", "12", "--seed", "4", "--policies",
                     f"paper, tuned={tmp_path / 'tuned.toml'}", "--assignment", "random"]) == 0
    out = capsys.readouterr().out
    assert "robot policies between subjects: paper " in out and "random, seeded by 4" in out
    study = load(path)
    assert study.policy_conditions == PolicyConditions(
        (("paper", "paper"), ("tuned", str(tmp_path / "tuned.toml"))), "random")
    assert [e.condition for e in study.participants] == allocate(
        study.policy_conditions, study.counterbalance.base,
        [e.order for e in study.participants], study.options, 4)
    for argv, message in [
        (["--policies", "paper,missing=nope.toml"], "policies.missing: no policy file"),
        (["--assignment", "random"], "--assignment goes with --policies"),
        (["--policies", "pa per"], "condition 'pa per' must be 1-32 letters"),
        (["--policies", "paper,paper"], "names a condition twice"),
        (["--policies", "paper", "--options", "3"], "two-option table only"),
    ]:
        new = tmp_path / "new.toml"
        assert cli.main(["init", str(new), "--participants", "4", *argv]) == 2
        assert message in _one_line_error(capsys)
        assert not new.exists()


def _trial(i: int) -> TrialRecord:
    return TrialRecord(i, "dissensus", None, "neutral", 0.0, 0.0, 1, 2, "red", "blue", "D",
                       0, 0, None, 0, "human pressed")


def test_start_next_and_status_carry_each_participants_condition(tmp_path, capsys):
    (tmp_path / "tuned.toml").write_text(PAPER_FILE)
    pc = PolicyConditions((("paper", "paper"), ("tuned", str(tmp_path / "tuned.toml"))))
    study = make_study("pilot", default_schedule(), 6, seed=4, policies=pc)
    path, db = tmp_path / "study.toml", tmp_path / "s.sqlite"
    write(study, path)
    p1, p2, p3 = study.participants[:3]
    store = Store(db)
    for e in (p1, p2, p3):
        record_consent(store, e.id, True, 1, {})
    # P01 done with their condition's policy; P02 done with the other; P03 crashed mid-session
    for session, e, ran, status in (("s1", p1, p1.condition, "complete"),
                                    ("s2", p2, p1.condition, "complete"),
                                    ("s3", p3, p3.condition, None)):
        store.begin_session(session, e.id, "rig1", 1, 10, {})
        store.write_trial(session, _trial(1), [])
        record_order(store, session, e.id, e.order, None, 10)
        begin_policy(store, session, *identity(pc.policy(ran or "")))
        if status is not None:
            store.finish_session(session, 11, status)
    store.close()

    assert cli.main(["next", str(path), "--db", str(db)]) == 0
    nxt = study.participants[3]
    assert (f"condition {nxt.condition} (--policy {pc.policy(nxt.condition or '')})"
            in capsys.readouterr().out)
    assert cli.main(["start", str(path), "--db", str(db), "--dry-run", "--sim",
                     "--participant", p3.id, "--again", "crashed"]) == 0
    assert f"--policy {pc.policy(p3.condition or '')}" in capsys.readouterr().out
    assert cli.main(["start", str(path), "--db", str(db), "--dry-run", "--participant", p1.id,
                     "--again", "x", "--", "--policy", "adaptive"]) == 2
    assert "--policy after --" in _one_line_error(capsys)

    assert cli.main(["status", str(path), "--db", str(db)]) == 0
    out = capsys.readouterr().out
    assert "conditions between subjects (counterbalanced): paper (--policy paper), tuned" in out
    rows = {line.split()[1]: line for line in out.splitlines() if re.match(r"\s+\d+\s+P\d", line)}
    assert all(f" {e.condition} " in rows[e.id] for e in study.participants)
    assert "not condition" not in rows[p1.id]
    ran = identity(pc.policy(p1.condition or ""))
    assert f"ran the policy {ran[0]} ({ran[1][:12]}), not condition {p2.condition}'s" in rows[
        p2.id]
    policy = pc.policy(p3.condition or "")
    assert f"resume: nod experiment --resume s3 --policy {policy}" in rows[p3.id]
    done = Counter(e.condition for e in (p1, p2))
    assert ("done per condition: " + ", ".join(f"{n} {done[n]}" for n in pc.names)) in out

    assert cli.main(["status", str(path), "--db", str(db), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["conditions"] == dict(pc.policies) and doc["assignment"] == "counterbalanced"
    assert [p["condition"] for p in doc["participants"]] == [
        e.condition for e in study.participants]
    assert doc["participants"][0]["sessions"][0]["policy"] == {"name": ran[0],
                                                               "sha256": ran[1]}
