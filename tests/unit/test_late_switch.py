"""The strategic late switch of the control trials (ParticipantParams.late_switch_*)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.closed_loop import run_offline_session
from services.model.geometry import Colour, TableLayout, colour_sign
from services.model.params import NodConfig
from services.model.participant import Participant, ParticipantParams, late_switch_chance
from services.model.schedule import default_schedule

LAYOUT = TableLayout()
# Always plays it: a strategist (share 1) who plays from the first control trial on.
STRATEGIST = ParticipantParams(late_switch_share=1.0, late_switch_first=1.0, preference_sd=0.0)
unit = st.floats(0.0, 1.0)


# -- the learning rule --------------------------------------------------------------------


@given(first=unit, learn=unit, n=st.integers(0, 50))
def test_the_chance_starts_at_first_and_only_grows_toward_one(first, learn, n):
    now, then = late_switch_chance(first, learn, n), late_switch_chance(first, learn, n + 1)
    assert late_switch_chance(first, learn, 0) == pytest.approx(first)
    assert first - 1e-12 <= now <= then <= 1.0
    # Each opposed trial removes the share `learn` of the remaining doubt.
    assert 1 - then == pytest.approx((1 - now) * (1 - learn), abs=1e-12)


@given(first=unit, n=st.integers(0, 50))
def test_with_no_learning_the_chance_stays_at_first(first, n):
    assert late_switch_chance(first, 0.0, n) == pytest.approx(first)


# -- one person, an arm that disagrees or agrees ------------------------------------------


def trial(person: Participant, option: Colour | None, arm_agrees: bool,
          dt: float = 0.002) -> list[tuple[float, float, int]]:
    """One trial with an arm that heads for (or against) the side the hand moves toward.

    Returns, for each step of `dt` until the press (or 6 s), the hand's (x, y) at the step's
    start (where the person decides) and the switches made by its end.
    """
    person.new_trial(option)
    t0 = t = person.t  # the person's clock runs on across trials
    person.go(t0)
    path = []
    side = 0  # the arm heads opposite the hand's first sideways move (dissensus), or with it
    while t < t0 + 6.0 and person.pressed is None:
        t += dt
        x, y = (float(v) for v in person.pos)
        if side == 0 and abs(x - 0.5) > 0.01:
            side = (1 if x > 0.5 else -1) * (1 if arm_agrees else -1)
        person.see_robot(t, side)
        person.advance(t)
        path.append((x, y, person.switches))
    return path


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), lead=st.floats(0.0, 0.2),
       speed=st.floats(1.0, 3.0))
def test_a_feint_turns_once_for_the_arm_side_just_before_the_commit_line(seed, lead, speed):
    params = replace(STRATEGIST, late_switch_lead=lead, late_switch_speed=speed)
    person = Participant(params, LAYOUT, seed)
    path = trial(person, None, arm_agrees=False)
    line = LAYOUT.commit.y
    turns = [i for i in range(1, len(path)) if path[i][2] > path[i - 1][2]]
    assert len(turns) == 1, turns  # one switch, the strategic one
    x, y, _ = path[turns[0]]
    # At the first step that starts within `lead` of the line (a 2 ms step covers < 0.002).
    assert line + lead - 0.002 <= y < line + lead, (y, line, lead)
    assert person.pressed is not None
    # It pressed the side the arm was on: the other side from where the hand first went.
    first = 1 if path[turns[0] // 2][0] > 0.5 else -1
    assert colour_sign(person.pressed) == -first


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_no_turn_when_the_arm_is_already_on_the_hand_side(seed):
    person = Participant(STRATEGIST, LAYOUT, seed)
    trial(person, None, arm_agrees=True)
    assert person.switches == 0 and person.pressed is not None


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), option=st.sampled_from(["red", "blue"]))
def test_a_strategist_plays_it_only_in_control_trials(seed, option):
    # Same random draws (a strategist either way), one plays it whenever it can, one never:
    # in a consensus trial they are the same person.
    eager = Participant(STRATEGIST, LAYOUT, seed)
    never = Participant(replace(STRATEGIST, late_switch_first=0.0, late_switch_learn=0.0),
                        LAYOUT, seed)
    for person in (eager, never):
        person.see_gaze(0.5 if option == "red" else -0.5)
    a = trial(eager, option, arm_agrees=False)
    b = trial(never, option, arm_agrees=False)
    assert a == b and eager.pressed == never.pressed


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_each_control_trial_with_an_opposing_arm_is_learnt_a_consensus_one_is_not(seed):
    person = Participant(replace(STRATEGIST, late_switch_first=0.0), LAYOUT, seed)
    for k in range(3):
        trial(person, None, arm_agrees=False)
        person.trial_ended(None)
        assert person.opposed_trials == k + 1
    trial(person, None, arm_agrees=True)  # an arm that never opposed the hand teaches nothing
    person.trial_ended(None)
    trial(person, "red", arm_agrees=False)  # nor does a consensus trial
    person.trial_ended("red")
    assert person.opposed_trials == 3


# -- off by default: the SPEC person is unchanged ------------------------------------------


@given(seed=st.integers(0, 2**31 - 1))
def test_with_no_strategists_the_person_draws_nothing_more(seed):
    # A person's random stream is its seed's, untouched by the trait: the SPEC person's
    # sessions are what they were before it existed.
    person = Participant(ParticipantParams(), LAYOUT, seed)
    assert not person.strategist
    assert person.rng.random() == np.random.default_rng(seed).random()


def control_config(participant: ParticipantParams) -> NodConfig:
    """The default config with only the three control trials and the given person."""
    cfg = NodConfig()
    control = tuple(t for t in default_schedule() if t.mode == "dissensus")
    return replace(cfg, participant=participant, protocol=replace(cfg.protocol, trials=control))


def outcomes(participant: ParticipantParams, seeds: range) -> list[tuple[str | None, int]]:
    """(outcome, violations) of every control trial of a cohort of these seeds."""
    cfg = control_config(participant)
    return [(t.outcome, t.violations) for s in seeds
            for t in run_offline_session(cfg, s, cohort=True)]


def test_the_other_traits_change_nothing_while_nobody_is_a_strategist():
    off = ParticipantParams()
    tuned = replace(off, late_switch_first=1.0, late_switch_learn=1.0, late_switch_speed=3.0,
                    late_switch_lead=0.2)
    assert outcomes(off, range(1, 4)) == outcomes(tuned, range(1, 4))


# -- in the closed loop: the robot of Algorithm 2 cannot follow a quick late turn ----------


def test_a_quick_late_turn_wins_the_robot_buzzer_a_slow_one_often_does_not():
    seeds = range(1, 9)
    quick = outcomes(replace(STRATEGIST, preference_sd=0.6, late_switch_speed=1.5), seeds)
    slow = outcomes(replace(STRATEGIST, preference_sd=0.6, late_switch_speed=1.0), seeds)
    nobody = outcomes(ParticipantParams(), seeds)
    share_c = [sum(o == "C" for o, _ in run) / len(run) for run in (quick, slow, nobody)]
    # The robot needs ≈ 1.3 s to see the turn, pause and cross back past the middle; a quick
    # turn from the line reaches the arm's box sooner, an ordinary-speed one only about half
    # the time; without strategists the robot (reading the hand correctly) always disagrees.
    assert share_c[0] >= 0.7, share_c
    assert share_c[1] <= share_c[0] - 0.2, share_c
    assert share_c[2] <= 0.05, share_c
    # Begun 0.1 before the line (the default lead), the turn is read before the hand crosses
    # it: no violation (a quicker turn needs more lead: at twice the speed 9 of 90 were late).
    assert sum(v for _, v in quick) <= 1, quick


@pytest.mark.parametrize(
    ("name", "value"),
    [("late_switch_share", -0.1), ("late_switch_share", 1.1), ("late_switch_first", 2.0),
     ("late_switch_learn", -1.0), ("late_switch_speed", 0.9), ("late_switch_speed", 6.0),
     ("late_switch_lead", -0.01), ("late_switch_lead", 0.31)],
)
def test_out_of_range_values_are_refused_by_name(name, value):
    with pytest.raises(ValueError, match=name):
        ParticipantParams(**{name: value})
