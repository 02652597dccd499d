"""The fit's stated prior: its file, its people, the cohort inside it, other populations."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.cohort.person import load_cohort_params
from services.core.config import ConfigError
from services.fit.pipeline import person_config
from services.fit.prior import (
    COHORT,
    KINDS,
    Prior,
    Range,
    load_prior,
    prior_from_mapping,
)
from services.fit.simulate import Population, load_population, true_person, truth
from services.model import closed_loop

KIND_FLAG = {"late_switcher": "strategist", "contrarian": "contrarian",
             "firm_contrarian": "firm", "persistent_contrarian": "persistent"}


def test_the_shipped_prior_varies_what_people_may_differ_in():
    prior = load_prior(None)
    assert not prior.is_cohort
    assert prior.names(load_cohort_params(None).participant) == (
        "preference_mean", "gaze_gain", "trust0", "speed", "reaction_s", "perception_delay_s",
        "gaze_use", "late_switcher", "contrarian", "firm_contrarian", "persistent_contrarian")
    assert load_prior("cohort") is COHORT and COHORT.is_cohort


def test_the_calibrated_cohort_is_one_population_inside_the_prior():
    """2000 people of the shipped cohort: at least 98 % lie within every range of the prior
    (gaze_gain's log-normal tails reach past it), and the prior is far wider than they are."""
    cfg = load_cohort_params(None)
    prior = load_prior(None)
    people = [true_person(cfg, seed) for seed in range(2000)]
    inside = np.mean([prior.contains(params, kinds) for params, kinds in people])
    assert inside >= 0.98
    pref = np.array([p.preference_mean for p, _ in people])
    wide = {r.name: r for r in prior.ranges}["preference_mean"]
    assert np.ptp(pref) < 0.05 * (wide.high - wide.low)  # the cohort: one preference size


def test_a_prior_person_is_the_person_the_session_simulates():
    """Person `seed` of the prior: the loop's participant has exactly the drawn traits and is
    of exactly the drawn kinds, and the truth vector reads them."""
    pop = Population(load_cohort_params(None), load_prior(None))
    seen = {kind: set() for kind, _ in KINDS}
    for seed in range(40):
        params, kinds = pop.person(seed)
        cfg = dataclasses.replace(pop.cfg, participant=params)
        loop = closed_loop._PaperLoop(cfg, seed, cohort=False, clicks=10)
        assert loop.person.p == params
        for kind, flag in KIND_FLAG.items():
            assert getattr(loop.person, flag) == kinds[kind]
            seen[kind].add(kinds[kind])
        theta = truth(params, kinds, pop.names)
        names = list(pop.names)
        assert theta[names.index("gaze_use")] == pytest.approx(params.gaze_gain * params.trust0)
        assert theta[names.index("preference_mean")] == params.preference_mean
        assert pop.person(seed) == (params, kinds)  # the same person every time
    assert all(v == {False, True} for v in seen.values())  # every kind both ways in 40


@settings(max_examples=40, deadline=None)
@given(st.floats(0.01, 10), st.floats(1.01, 100), st.sampled_from(["linear", "log"]),
       st.integers(0, 2**32 - 1))
def test_every_draw_lies_in_its_range_and_the_log_scale_is_even_on_the_log(low, ratio, scale,
                                                                          seed):
    r = Range("speed", low, low * ratio, scale)
    rng = np.random.default_rng(seed)
    values = np.array([r.draw(rng) for _ in range(400)])
    assert np.all((low <= values) & (values <= low * ratio))
    on = np.log(values) if scale == "log" else values
    a, b = (math.log(low), math.log(low * ratio)) if scale == "log" else (low, low * ratio)
    assert abs(np.mean(on) - (a + b) / 2) < 0.1 * (b - a)  # uniform on its own scale


def test_another_range_changes_that_trait_only():
    base = load_cohort_params(None).participant
    one = Prior((Range("speed", 0.2, 0.4), Range("reaction_s", 0.1, 0.6)), (("contrarian", 0.5),))
    two = dataclasses.replace(one, ranges=(Range("speed", 0.2, 0.3), one.ranges[1]))
    for seed in range(5):
        p1, p2 = (pr.draw(base, np.random.default_rng(seed)) for pr in (one, two))
        assert p1.reaction_s == p2.reaction_s and p1.speed != p2.speed
        assert p1.contrarian_share == p2.contrarian_share in (0.0, 1.0)
    assert one.digest() != two.digest()
    cfg = load_cohort_params(None)
    keys = {Population(cfg).key(), Population(cfg, one).key(), Population(cfg, two).key()}
    assert len(keys) == 3  # each its own cached table


@pytest.mark.parametrize(("data", "says"), [
    ({"traits": {"nonsense": {"low": 0, "high": 1}}}, "not a float trait"),
    ({"traits": {"speed": {"low": 0.4, "high": 0.2}}}, "low <= high"),
    ({"traits": {"gaze_gain": {"low": 0, "high": 9, "scale": "log"}}}, "low > 0"),
    ({"traits": {"speed": {"low": 0.2, "high": 0.4, "scale": "cubic"}}}, "scale must be"),
    ({"traits": {"speed": {"low": "fast", "high": 0.4}}}, "must be numbers"),
    ({"kinds": {"wizard": 0.5}}, "not a kind"),
    ({"kinds": {"contrarian": 1.5}}, "probability in [0, 1]"),
    ({"participant": {}}, "unknown table"),
    ({}, "states no trait and no kind"),
])
def test_a_bad_prior_file_says_which_key_and_why(data, says):
    with pytest.raises(ConfigError, match=None) as err:
        prior_from_mapping(data, "p.toml")
    assert says in str(err.value) and "p.toml" in str(err.value)


def test_a_population_file_is_a_cohort_or_a_prior_over_it(tmp_path):
    split = tmp_path / "split.toml"
    split.write_text("[participant]\npreference_spread = 0.8\nmin_conviction = 0.2\n")
    pop = load_population(split)
    assert pop.prior.is_cohort and pop.cfg.participant.preference_spread == 0.8
    assert pop.person(5) == true_person(pop.cfg, 5)
    ranged = tmp_path / "ranged.toml"
    ranged.write_text("[participant]\nmin_conviction = 0.2\n"
                      "[traits.preference_mean]\nlow = 1.0\nhigh = 5.0\n")
    pop = load_population(ranged)
    assert pop.cfg.participant.min_conviction == 0.2
    # The kinds it leaves unstated are the cohort's: drawn by the person, so still fitted.
    assert pop.names == ("preference_mean", "late_switcher", "contrarian", "firm_contrarian",
                         "persistent_contrarian")
    for seed in range(10):
        params, kinds = pop.person(seed)
        assert 1.0 <= params.preference_mean <= 5.0
        assert params.contrarian_share == pop.cfg.participant.contrarian_share
        loop = closed_loop._PaperLoop(dataclasses.replace(pop.cfg, participant=params), seed,
                                      cohort=False, clicks=10)
        assert all(getattr(loop.person, flag) == kinds[k] for k, flag in KIND_FLAG.items())


def test_a_posterior_draw_under_a_prior_is_of_the_prior_s_certain_kinds():
    """A kind the prior makes certain is everyone's: the predictive person is of it too; the
    kinds it leaves to the cohort (firm, persistent among contrarians) are fitted and set."""
    cfg = load_cohort_params(None)
    prior = Prior((Range("speed", 0.2, 0.4),), (("contrarian", 1.0), ("late_switcher", 0.5)))
    pop = Population(cfg, prior)
    assert pop.names == ("speed", "late_switcher", "firm_contrarian", "persistent_contrarian")
    person = person_config(pop, pop.names, np.array([0.3, 1.0, 0.0, 1.0])).participant
    assert person.speed == 0.3 and person.late_switch_share == 1.0
    assert person.contrarian_share == 1.0 and cfg.participant.contrarian_share < 1.0
    assert (person.contrarian_firm, person.contrarian_persist) == (0.0, 1.0)
    assert person_config(Population(cfg), ("speed",), np.array([0.3])).participant == (
        dataclasses.replace(cfg.participant, speed=0.3))  # the cohort: its own shares
