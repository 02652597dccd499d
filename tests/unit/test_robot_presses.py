"""The conductor takes the robot's press only when the arm's own state confirms it.

One rule for any option set: a box is a colour on the paper's keys and an index on a table of
N boxes (`services.experiment.keyspace`), so each test runs with both namings.
"""

import pytest

from services.experiment.presses import RobotPresses

NAMINGS = {"paper": ("red", "blue"), "three boxes": (2, 0)}


@pytest.fixture(params=list(NAMINGS), ids=list(NAMINGS))
def boxes(request):
    return NAMINGS[request.param]


def test_a_press_before_its_state_waits_and_is_taken_when_the_arm_shows_it(boxes):
    a, _ = boxes
    p = RobotPresses()
    p.begin(2)
    p.arm_state(2, "pressing", a)
    p.press(2, a)  # the usual order: the press arrives before the "done" state
    assert p.confirmed is None
    p.arm_state(2, "done", a)
    assert p.confirmed == a and p.unconfirmed() == [] and p.refused == 0


def test_forged_presses_are_never_confirmed_and_are_counted_at_the_end(boxes):
    a, b = boxes
    p = RobotPresses()
    p.begin(2)
    for box in (b, a, b):
        p.press(2, box)  # forged: the arm is still on its way
        p.press(1, box)  # another trial's: ignored
    p.arm_state(2, "moving", a)
    p.arm_state(2, "done", a)  # the arm really pressed a
    assert p.confirmed == a
    assert p.unconfirmed() == [b] and p.refused == 1
    p.begin(3)
    assert p.confirmed is None and p.unconfirmed() == []


def test_a_state_of_another_trial_confirms_nothing(boxes):
    _, b = boxes
    p = RobotPresses()
    p.begin(3)
    p.arm_state(2, "done", b)  # a late state of the previous trial
    p.press(3, b)
    assert p.confirmed is None
    p.arm_state(3, "done", b)
    assert p.confirmed == b
