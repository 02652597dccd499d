"""How the own preference's variance splits between people and trials (preference_spread/_sd)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.geometry import TableLayout
from services.model.participant import Participant, ParticipantParams, jittered

BASE = ParticipantParams(preference_mean=3.0)  # far enough above jittered's floor of 0.5


@given(seed=st.integers(0, 2**31 - 1))
def test_the_default_spread_draws_the_people_it_drew_before_it_was_a_trait(seed):
    # Before the trait, jittered drew preference_mean with a fixed sd of 0.4: the SPEC person's
    # cohorts (and every store simulated from them) are unchanged.
    base = ParticipantParams()
    person = jittered(base, np.random.default_rng(seed))
    rng = np.random.default_rng(seed)
    assert person.preference_mean == max(0.5, rng.normal(base.preference_mean, 0.4))
    assert person.trust0 == max(0.1, rng.normal(base.trust0, 0.25))  # the stream goes on alike


@given(seed=st.integers(0, 2**31 - 1))
def test_with_no_spread_every_person_holds_the_cohort_mean(seed):
    person = jittered(replace(BASE, preference_spread=0.0), np.random.default_rng(seed))
    assert person.preference_mean == BASE.preference_mean


@settings(max_examples=5, deadline=None)
@given(spread=st.floats(0.1, 0.8), seed=st.integers(0, 2**31 - 1))
def test_the_spread_is_the_sd_of_the_person_means(spread, seed):
    rng = np.random.default_rng(seed)
    means = [jittered(replace(BASE, preference_spread=spread), rng).preference_mean
             for _ in range(2000)]
    # 2000 draws put the sample sd within ≈ 5 % of the truth (3 standard errors ≈ 4.7 %).
    assert math.isclose(float(np.std(means)), spread, rel_tol=0.08)
    assert math.isclose(float(np.mean(means)), BASE.preference_mean, abs_tol=0.1)


@settings(max_examples=5, deadline=None)
@given(sd=st.floats(0.05, 0.8), seed=st.integers(0, 2**31 - 1))
def test_a_person_s_trials_scatter_by_preference_sd_around_their_own_mean(sd, seed):
    person = Participant(replace(BASE, preference_sd=sd), TableLayout(), seed)
    strengths = []
    for _ in range(2000):
        person.new_trial(None)
        strengths.append(abs(person.b_h))
    assert math.isclose(float(np.std(strengths)), sd, rel_tol=0.08)
    assert math.isclose(float(np.mean(strengths)), BASE.preference_mean, abs_tol=0.1)


@pytest.mark.parametrize("name", ["preference_spread", "preference_sd"])
def test_a_negative_spread_or_sd_is_refused(name):
    with pytest.raises(ValueError, match=name):
        ParticipantParams(**{name: -0.1})
