"""The simulated participant: the arm it sees against the eyes' cue; no C in control trials."""

from __future__ import annotations

from dataclasses import replace

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from services.model.closed_loop import run_offline_session
from services.model.geometry import TableLayout
from services.model.params import NodConfig
from services.model.participant import Participant, ParticipantParams
from services.model.protocol import default_schedule
from services.sim.fit import TRAITS, with_traits

# A person with no private preference (so the seed cannot choose a side) whom the eyes pull
# toward red with b_h = 1.5: weaker than the arm's largest pull (u = 2.24), so an arm seen
# going to blue, believed fully, wins.
TORN = ParticipantParams(preference_mean=0.0, preference_sd=0.0, gaze_gain=3.0, trust0=1.0,
                         gaze_gain_spread=0.0)


def run(params: ParticipantParams, yaw: float, arm: int, seconds: float = 1.5) -> Participant:
    """A trial where the eyes look at yaw and the arm is seen heading `arm` from "go" on."""
    person = Participant(params, TableLayout(), seed=5)
    person.see_gaze(yaw)
    person.new_trial("red" if yaw > 0 else None)
    person.go(0.0)
    t = 0.0
    while t < seconds and person.pressed is None:
        t += 1 / 30
        person.see_robot(t, arm)
        person.advance(t)
    return person


def test_an_arm_against_the_eyes_wins_over_a_person_who_believes_it():
    person = run(replace(TORN, gaze_over_robot=0.0), yaw=0.5, arm=-1)
    assert person.z_h < 0  # follows the arm to blue, against the eyes


def test_a_person_who_trusts_the_eyes_discounts_an_arm_going_against_them():
    person = run(replace(TORN, gaze_over_robot=4.0), yaw=0.5, arm=-1)
    assert person.z_h > 0  # keeps to red, where the eyes look
    assert person.switches == 0


def test_an_arm_that_agrees_with_the_eyes_is_never_discounted():
    a = run(replace(TORN, gaze_over_robot=0.0), yaw=0.5, arm=+1)
    b = run(replace(TORN, gaze_over_robot=4.0), yaw=0.5, arm=+1)
    assert a.z_h == b.z_h and a.pos.tolist() == b.pos.tolist()


@pytest.mark.parametrize("arm", [-1, +1])
def test_with_neutral_eyes_the_trait_changes_nothing(arm):
    a = run(replace(TORN, preference_mean=2.0, gaze_over_robot=0.0), yaw=0.0, arm=arm)
    b = run(replace(TORN, preference_mean=2.0, gaze_over_robot=4.0), yaw=0.0, arm=arm)
    assert a.z_h == b.z_h and a.pos.tolist() == b.pos.tolist()


def test_a_negative_discount_is_refused():
    with pytest.raises(ValueError, match="gaze_over_robot"):
        ParticipantParams(gaze_over_robot=-0.1)


# -- the claim docs/study.md makes about the control trials ---------------------------------


def _control_config(traits: dict[str, float], labels: str = "switches") -> NodConfig:
    """The default config with only the three control trials, the given traits and labelling."""
    control = tuple(t for t in default_schedule() if t.mode == "dissensus")
    cfg = NodConfig()
    cfg = replace(cfg, protocol=replace(cfg.protocol, trials=control, control_labels=labels))
    return with_traits(cfg, traits)


@settings(max_examples=25, deadline=None)
@given(
    unit=st.lists(st.floats(0.0, 1.0), min_size=len(TRAITS), max_size=len(TRAITS)),
    seed=st.integers(1, 10_000),
)
# Found by this test: a hand too slow for the observer to read (ẑ_h stayed 0, the arm never
# moved) reached blue after the timeout while the arm went to press blue: that late press was
# counted as the person's, a C. The trial is a timeout (SessionProtocol's TrialEnd.counted_press).
@example(unit=[1.0] + [0.0] * (len(TRAITS) - 1), seed=1)
def test_no_person_the_calibration_can_reach_gets_c_in_a_control_trial(unit, seed):
    # With the robust observer the robot reads the hand's side from its first movement and heads
    # the other way; it turns only after the hand's reading changed side, which the outcome
    # counts as a switch. So under the switch rule (`control_labels = "switches"`) a control
    # trial is D, CH or DH for every person in the fitted traits' ranges — why SPEC §6 labels
    # control trials by agreement alone, as the paper's Fig 8a does (docs/study.md).
    traits = {t.name: t.low + (t.high - t.low) * u for t, u in zip(TRAITS, unit, strict=True)}
    trials = run_offline_session(_control_config(traits), seed, cohort=True)
    assert [t.mode for t in trials] == ["dissensus"] * 3
    assert all(t.outcome != "C" for t in trials), [(t.outcome, t.switches) for t in trials]
    # By agreement (the default): the same people, the same presses and switches, C or D only —
    # C exactly where they pressed the robot's buzzer, which took a switch.
    agreed = run_offline_session(_control_config(traits, "agreement"), seed, cohort=True)
    for by_switches, by_agreement in zip(trials, agreed, strict=True):
        assert (by_agreement.human, by_agreement.robot, by_agreement.switches) == (
            by_switches.human, by_switches.robot, by_switches.switches)
        expected = {"CH": "C", "DH": "D", "D": "D", None: None}[by_switches.outcome]
        assert by_agreement.outcome == expected, (by_switches, by_agreement)
