"""The conductor takes the robot's press only when the arm's own state confirms it."""

from services.core import messages as m
from services.experiment.presses import RobotPresses


def press(colour: str, trial: int = 2) -> m.PressMsg:
    return m.PressMsg(seq=0, t_ns=0, colour=colour, trial=trial)


def test_a_press_before_its_state_waits_and_is_taken_when_the_arm_shows_it():
    p = RobotPresses()
    p.begin(2)
    p.arm_state(2, "pressing", "red")
    p.press(press("red"))  # the usual order: the press arrives before the "done" state
    assert p.confirmed is None
    p.arm_state(2, "done", "red")
    assert p.confirmed == "red" and p.unconfirmed() == [] and p.refused == 0


def test_forged_presses_are_never_confirmed_and_are_counted_at_the_end():
    p = RobotPresses()
    p.begin(2)
    for colour in ("blue", "red", "blue"):
        p.press(press(colour))  # forged: the arm is still on its way
        p.press(press(colour, trial=1))  # another trial's: ignored
    p.arm_state(2, "moving", "red")
    p.arm_state(2, "done", "red")  # the arm really pressed red
    assert p.confirmed == "red"
    assert p.unconfirmed() == ["blue"] and p.refused == 1
    p.begin(3)
    assert p.confirmed is None and p.unconfirmed() == []


def test_a_state_of_another_trial_confirms_nothing():
    p = RobotPresses()
    p.begin(3)
    p.arm_state(2, "done", "blue")  # a late state of the previous trial
    p.press(press("blue", trial=3))
    assert p.confirmed is None
    p.arm_state(3, "done", "blue")
    assert p.confirmed == "blue"
