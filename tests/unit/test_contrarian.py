"""The person who distrusts the eyes in consensus trials (ParticipantParams.contrarian_*)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.closed_loop import run_offline_session
from services.model.geometry import TableLayout, colour_sign
from services.model.params import NodConfig
from services.model.participant import Participant, ParticipantParams

LAYOUT = TableLayout()
# Everybody a contrarian who never comes round; no trial-to-trial noise in the preference.
CONTRARIAN = ParticipantParams(contrarian_share=1.0, contrarian_learn=0.0, preference_sd=0.0)


def first_heading(person: Participant, option: str | None, yaw: float) -> int:
    """Start a trial with the eyes at `yaw`; the side (+1 red, −1 blue) the hand first heads."""
    person.see_gaze(yaw)
    person.new_trial(option)  # type: ignore[arg-type]
    t0 = person.t
    person.go(t0)
    t = t0
    while t < t0 + 3.0:
        t += 0.01
        person.advance(t)
        x = float(person.pos[0])
        if abs(x - 0.5) > 0.02:
            return 1 if x > 0.5 else -1
    return 0


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), toward_red=st.booleans(), yaw=st.floats(0.1, 0.6))
def test_a_contrarian_heads_for_the_box_the_eyes_do_not_look_at(seed, toward_red, yaw):
    signed = yaw if toward_red else -yaw
    option = "red" if toward_red else "blue"
    contrarian = Participant(CONTRARIAN, LAYOUT, seed)
    assert contrarian.contrarian
    assert first_heading(contrarian, option, signed) == -colour_sign(option)
    assert contrarian.contrary_trials == 1
    # Trust is neither earned nor lost in a trial played against the eyes.
    trust = contrarian.trust
    contrarian.trial_ended(option)
    assert contrarian.trust == trust


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_in_a_control_trial_a_contrarian_is_anyone(seed):
    # Same draws (a contrarian either way, learning or not): in a control trial, whose eyes look
    # at no option, the contrarian plays nothing and both people move the same way.
    a = Participant(CONTRARIAN, LAYOUT, seed)
    b = Participant(replace(CONTRARIAN, contrarian_learn=1.0), LAYOUT, seed)
    assert first_heading(a, None, 0.3) == first_heading(b, None, 0.3)
    assert a.contrary_trials == b.contrary_trials == 0


def test_a_contrarian_comes_round_at_the_rate_it_learns():
    # The chance of playing against the eyes falls by the share `contrarian_learn` with each
    # consensus trial so played: with 0.5, about 1, ½, ¼ … of trials 1, 2, 3 … of the phase.
    played = np.zeros(5)
    people = 200
    for seed in range(people):
        person = Participant(replace(CONTRARIAN, contrarian_learn=0.5), LAYOUT, seed)
        for k in range(5):
            before = person.contrary_trials
            first_heading(person, "red", 0.4)
            played[k] += person.contrary_trials - before
    share = played / people
    assert share[0] == 1.0
    assert share[1] == pytest.approx(0.5, abs=0.1)
    assert all(share[k + 1] < share[k] for k in range(4)), share


def test_a_persistent_contrarian_never_comes_round_the_others_do():
    # Half the contrarians persistent, the others learning everything after one trial: the
    # persistent play all five consensus trials against the eyes, the others only the first.
    params = replace(CONTRARIAN, contrarian_learn=1.0, contrarian_persist=0.5)
    kinds = {True: 0, False: 0}
    for seed in range(60):
        person = Participant(params, LAYOUT, seed)
        for _ in range(5):
            first_heading(person, "red", 0.4)
        assert person.contrary_trials == (5 if person.persistent else 1), seed
        kinds[person.persistent] += 1
    assert kinds[True] >= 15 and kinds[False] >= 15, kinds  # both kinds drawn, near half


@given(seed=st.integers(0, 2**31 - 1))
def test_without_persistent_contrarians_a_contrarian_draws_nothing_more(seed):
    # The shipped cohort has none: adding the trait must not move its people's random streams.
    params = replace(CONTRARIAN, contrarian_firm=0.5)
    person = Participant(params, LAYOUT, seed)
    twin = np.random.default_rng(seed)
    twin.random(), twin.random()  # contrarian? firm? (no strategists here: no draw)
    assert not person.persistent
    assert person.rng.random() == twin.random()


@given(seed=st.integers(0, 2**31 - 1))
def test_with_no_contrarians_the_person_draws_nothing_more(seed):
    person = Participant(ParticipantParams(), LAYOUT, seed)
    assert not person.contrarian
    assert person.rng.random() == np.random.default_rng(seed).random()


def test_the_other_traits_change_nothing_while_nobody_is_a_contrarian():
    off = NodConfig()
    tuned = replace(off, participant=replace(off.participant, contrarian_learn=0.9,
                                             contrarian_resolve=0.1, contrarian_firm=1.0))
    runs = [[(t.outcome, t.switches, t.press_s) for s in range(1, 4)
             for t in run_offline_session(cfg, s, cohort=True)] for cfg in (off, tuned)]
    assert runs[0] == runs[1]


def test_firm_contrarians_stay_away_pliant_ones_come_over_to_the_robot():
    """In the closed loop the arm goes for O: a pliant contrarian follows it (CH), a firm one
    mostly keeps the other box (D); neither is C, and the eyes' followers mostly are."""
    cfg = NodConfig()

    def consensus(**traits: float) -> list[str | None]:
        person = replace(cfg.participant, **traits)  # type: ignore[arg-type]
        c = replace(cfg, participant=person)
        return [t.outcome for s in range(1, 9) for t in run_offline_session(c, s, cohort=True)
                if t.mode == "consensus"]

    pliant = consensus(contrarian_share=1.0, contrarian_learn=0.0, contrarian_resolve=0.2)
    firm = consensus(contrarian_share=1.0, contrarian_learn=0.0, contrarian_firm=1.0)
    share = {name: {o: run.count(o) / len(run) for o in ("C", "CH", "D", "DH")}
             for name, run in (("pliant", pliant), ("firm", firm))}
    assert share["pliant"]["C"] <= 0.1 and share["pliant"]["CH"] >= 0.6, share
    assert share["firm"]["C"] <= 0.1 and share["firm"]["D"] + share["firm"]["DH"] >= 0.5, share
    assert share["firm"]["D"] > share["pliant"]["D"], share


@pytest.mark.parametrize(
    ("name", "value"),
    [("contrarian_share", -0.1), ("contrarian_share", 1.1), ("contrarian_learn", 2.0),
     ("contrarian_firm", -0.5), ("contrarian_resolve", -0.1), ("contrarian_resolve", 2.5),
     ("contrarian_persist", 1.5)],
)
def test_out_of_range_values_are_refused_by_name(name, value):
    with pytest.raises(ValueError, match=name):
        ParticipantParams(**{name: value})
