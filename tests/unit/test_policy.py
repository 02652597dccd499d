"""The robot policy (services/model/policy.py): its envelope, the paper's robot, the freeze."""

from __future__ import annotations

import dataclasses
import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.cohort.person import load_cohort_params
from services.model.closed_loop import run_offline_session
from services.model.decision import DecisionModel, DecisionParams
from services.model.gaze import GAZE_LEVEL_NAMES
from services.model.observer import ObserverParams
from services.model.policy import (
    KINDS,
    OUTCOMES,
    AdaptivePolicy,
    Counts,
    Envelope,
    OutcomeTable,
    PaperPolicy,
    Played,
    PolicyRun,
    PolicySettings,
    cued_before,
    decision_for,
    paper_settings,
)
from services.model.schedule import default_schedule

SPECS = default_schedule()
PAPER = PolicySettings(4.54, "low", 2.24)

levels = st.sampled_from(GAZE_LEVEL_NAMES)
anything = st.builds(PolicySettings, st.floats(-50, 50), levels, st.floats(-50, 50))
envelopes = st.builds(
    lambda b, u, g: Envelope((min(b), max(b)), (min(u), max(u)), tuple(g)),
    st.tuples(st.floats(0.1, 8), st.floats(0.1, 8)),
    st.tuples(st.floats(0.1, 5), st.floats(0.1, 5)),
    st.lists(levels, min_size=1, max_size=6, unique=True),
)


def wild_table(candidates: list[PolicySettings], counts: list[int]) -> OutcomeTable:
    """A table whose candidates may lie anywhere (an adaptive policy's worst case)."""
    it = itertools.cycle(counts)
    cells = {
        (s, t, cued): {k: Counts(tuple(next(it) for _ in OUTCOMES), next(it), next(it))
                       for k in KINDS}
        for s in candidates for t in range(1, 9) for cued in range(5)
    }
    return OutcomeTable(tuple(candidates), {k: 1 + next(it) for k in KINDS}, cells)


history = st.lists(
    st.builds(Played, st.integers(1, 8), st.sampled_from(("dissensus", "consensus")), anything,
              st.sampled_from((*OUTCOMES[:4], None)), st.booleans()),
    max_size=8,
)


@settings(max_examples=200, deadline=None)
@given(envelopes, st.lists(anything, min_size=1, max_size=5),
       st.lists(st.integers(0, 30), min_size=1, max_size=7), history, st.booleans())
def test_adaptive_settings_never_leave_the_envelope(env, candidates, counts, past, freeze):
    run = PolicyRun(AdaptivePolicy(wild_table(candidates, counts)), env)
    for played in past:
        run.played(played)
    for spec in SPECS:
        if freeze and spec.index == 6:
            run.freeze()
        s = run.settings(spec, paper_settings(DecisionParams(), spec))
        assert env.contains(s), (s, env)


def test_the_default_envelope_holds_the_papers_robot():
    env = Envelope()
    assert all(env.contains(paper_settings(DecisionParams(), spec)) for spec in SPECS)
    assert env.clip(PolicySettings(9.0, "extreme", 0.1)) == PolicySettings(6.0, "extreme", 1.5)
    narrow = Envelope(gaze_levels=("neutral", "low"))
    assert narrow.clip(PolicySettings(4.0, "minimal", 2.0)).gaze_level == "neutral"  # a tie
    assert narrow.clip(PolicySettings(4.0, "extreme", 2.0)).gaze_level == "low"
    with pytest.raises(ValueError, match=r"\[policy\] b_star"):
        Envelope(b_star=(5.0, 4.0))
    with pytest.raises(ValueError, match=r"\[policy\] gaze_levels"):
        Envelope(gaze_levels=("sideways",))  # type: ignore[arg-type]


def test_a_frozen_policy_keeps_its_last_settings():
    bold = PolicySettings(6.0, "extreme", 2.0)
    table = OutcomeTable((bold,), {k: 1 for k in KINDS})
    run = PolicyRun(AdaptivePolicy(table), Envelope())
    chosen = {}
    for spec in SPECS:
        if spec.index == 5:
            run.freeze()
        chosen[spec.index] = run.settings(spec, paper_settings(DecisionParams(), spec))
    assert chosen[4] == bold  # consensus: the only candidate
    assert [chosen[i] for i in (5, 6, 7, 8)] == [bold] * 4  # frozen at trial 4's
    run = PolicyRun(AdaptivePolicy(table), Envelope())
    run.settings(SPECS[1], paper_settings(DecisionParams(), SPECS[1]))
    run.freeze()  # frozen in the control trials: the paper's neutral gaze stays
    assert all(run.settings(s, paper_settings(DecisionParams(), s)).gaze_level == "neutral"
               for s in SPECS[3:])


def test_freezing_in_the_loop_keeps_the_settings_of_the_trial_before():
    cfg = load_cohort_params(None)
    bold = PolicySettings(6.0, "extreme", 2.0)
    run = PolicyRun(AdaptivePolicy(OutcomeTable((bold,), {k: 1 for k in KINDS})), cfg.policy)
    run.settings(SPECS[0], paper_settings(cfg.decision, SPECS[0]))
    trials = run_offline_session(cfg, 3, cohort=True, policy=run)
    assert [t.settings for t in trials[3:]] == [bold] * 5
    frozen = PolicyRun(PaperPolicy(), cfg.policy)
    frozen.freeze()
    frozen.last = bold  # as if the operator froze it on a bold trial
    trials = run_offline_session(cfg, 3, cohort=True, policy=frozen)
    assert [t.settings for t in trials] == [bold] * 8


@pytest.mark.parametrize("seed", [1, 7])
def test_the_paper_policy_is_todays_robot_trial_for_trial(seed):
    cfg = load_cohort_params(None)
    today = run_offline_session(cfg, seed, cohort=True, record=True)
    paper = run_offline_session(cfg, seed, cohort=True, record=True, policy=PaperPolicy())
    assert [dataclasses.replace(t, settings=None) for t in paper] == today
    assert [t.settings for t in paper] == [paper_settings(cfg.decision, s) for s in SPECS]


def test_retune_sets_the_engines_threshold():
    engine = DecisionModel(DecisionParams())
    assert engine.b_star == pytest.approx(4.54)
    engine.retune(decision_for(DecisionParams(), PolicySettings(6.0, "low", 2.0)))
    assert (engine.b_star, engine.params.pair.robot.u) == (6.0, 2.0)
    other = dataclasses.replace(DecisionParams(), observer=ObserverParams(a=4.0))
    with pytest.raises(ValueError, match="observer"):
        engine.retune(other)


def test_the_policys_settings_reach_the_robot():
    """A bolder b* and the extreme gaze change what the robot and the person do."""
    cfg = load_cohort_params(None)
    bold = PolicySettings(6.0, "extreme", 2.24)
    table = OutcomeTable((bold,), {k: 1 for k in KINDS})
    runs = [run_offline_session(cfg, s, cohort=True, record=True,
                                policy=AdaptivePolicy(table)) for s in range(1, 4)]
    for trials in runs:
        assert [t.settings for t in trials[3:]] == [bold] * 5
        assert trials[0].settings == paper_settings(cfg.decision, SPECS[0])
    today = [run_offline_session(cfg, s, cohort=True, record=True) for s in range(1, 4)]
    for trials, before in zip(runs, today, strict=True):
        # the bias's first frame of growth is ≈ β · b* · Δt: b* = 6 against today's 4.54
        first = [next(abs(x.b_r) for x in t[3].samples if x.b_r) for t in (trials, before)]
        assert first[0] > 1.2 * first[1]
    assert [t[:3] for t in today] == [[dataclasses.replace(x, settings=None) for x in t[:3]]
                                      for t in runs]  # the control trials are today's


def test_the_cues_before_a_trial_and_the_posterior_they_read():
    cue, none = PolicySettings(4.54, "extreme", 2.24), PolicySettings(4.54, "neutral", 2.24)
    past = [Played(2, "dissensus", PolicySettings(4.54, "neutral", 2.24), "D", False),
            Played(4, "consensus", cue, "CH", True), Played(5, "consensus", none, "C", True),
            Played(6, "consensus", cue, "D", False)]
    assert [cued_before(past, t) for t in (4, 5, 6, 7)] == [0, 1, 1, 2]
    # a table where only contrarians end trial 4 CH under a cue: one CH makes one a contrarian
    cells = {(cue, 4, 0): {k: Counts((9, 1, 0, 0, 0) if k != "contrarian" else (0, 9, 1, 0, 0),
                                     9 if k != "contrarian" else 0, 10) for k in KINDS}}
    table = OutcomeTable((cue, none), {k: 10 for k in KINDS}, cells)
    post = table.posterior(past[:2])
    assert post["contrarian"] == pytest.approx(0.76 / (0.76 + 3 * 0.12))
    assert sum(post.values()) == pytest.approx(1.0)
    assert table.posterior([]) == pytest.approx({k: 0.25 for k in KINDS})


def test_the_rule_plans_past_the_next_trial():
    """A cue that costs now and pays later (a contrarian taught by it) is taken."""
    cue, none = PolicySettings(4.54, "extreme", 2.24), PolicySettings(4.54, "neutral", 2.24)

    def cell(c_in_100: int) -> dict:
        return {k: Counts((100, 0, 0, 0, 0), c_in_100, c_in_100) for k in KINDS}

    cells = {(none, 4, 0): cell(50), (cue, 4, 0): cell(30),
             (none, 5, 0): cell(50), (cue, 5, 0): cell(30),
             (none, 5, 1): cell(50), (cue, 5, 1): cell(90)}
    policy = AdaptivePolicy(OutcomeTable((none, cue), {k: 1 for k in KINDS}, cells))
    spec4, spec5 = SPECS[3], SPECS[4]
    assert policy.choose(spec4, PAPER, []) == cue  # 0.3 + 0.9 over 0.5 + 0.5
    assert policy.choose(spec5, PAPER, [Played(4, "consensus", cue, "D", False)]) == cue
    assert policy.choose(spec5, PAPER, [Played(4, "consensus", none, "C", True)]) == none
    assert policy.plan(4, 0, {k: 0.25 for k in KINDS})[0] == pytest.approx(31 / 102 + 91 / 102)
