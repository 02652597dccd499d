"""Algorithm 2 over N_o boxes: today's behaviour with two, a debounced argmax with more."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.behaviour import ArmCommand, RobotBehaviour
from services.model.debounce import SignDebouncer
from services.model.geometry import Colour, OptionsLayout, TableLayout
from services.model.options_behaviour import LeaderDebouncer, OptionsBehaviour, OptionsCommand

samples = st.lists(st.sampled_from([-1.0, -0.3, 0.0, 0.2, 1.0]), min_size=1, max_size=60)


@settings(max_examples=200, deadline=None)
@given(samples, st.integers(1, 5))
def test_two_options_debounce_as_the_sign(xs: list[float], c_max: int) -> None:
    sign, leader = SignDebouncer(c_max), LeaderDebouncer(c_max)
    for x in xs:
        assert leader.feed(np.array([x, -x])) == sign.feed(x)
        assert leader.leader == {1: 0, -1: 1, 0: None}[sign.sign]
        if sign.sign:
            assert leader.onset == sign.onset


def test_a_third_option_restarts_the_run() -> None:
    deb = LeaderDebouncer(3)
    a, b, c = (np.eye(3)[j] * 2 - 2 / 3 for j in range(3))
    deb.feed(a)
    assert not deb.feed(b) and not deb.feed(b)
    assert not deb.feed(c)  # a run toward b interrupted by c: the count starts over for c
    assert not deb.feed(c) and deb.feed(c)
    assert deb.leader == 2
    assert not deb.feed(np.array([1.0, 1.0, -2.0]))  # a tie carries no option
    assert deb.leader == 2


def as_options(cmd: ArmCommand) -> OptionsCommand:
    target = {"red": 0, "blue": 1, None: None}[cmd.target]
    return OptionsCommand(cmd.action, target, "")


@settings(max_examples=100, deadline=None)
@given(
    st.lists(st.tuples(st.sampled_from([-1.0, 0.0, 0.5, 1.0, None]), st.booleans()),
             min_size=1, max_size=80),
    st.floats(0.2, 0.8),
)
def test_two_boxes_command_the_arm_as_today(
    stream: list[tuple[float | None, bool]], x: float
) -> None:
    table = TableLayout()
    today = RobotBehaviour(table)
    options = OptionsBehaviour(OptionsLayout.from_table(table))
    assert as_options(today.start(0.0, 10.0)).action == options.start(0.0, 10.0).action
    ee = (x, 0.5)
    for i, (z, press) in enumerate(stream):
        t = 0.03 * (i + 1)
        pressed: Colour | None = "red" if press and i % 7 == 6 else None
        want = today.step(t, z, pressed, ee)
        got = options.step(t, None if z is None else np.array([z, -z]),
                           None if pressed is None else 0, ee)
        assert (got.action, got.target) == (as_options(want).action, as_options(want).target)
        assert options.phase == today.phase


def test_three_boxes_follow_the_leader_and_press_the_nearest() -> None:
    layout = OptionsLayout.row(3)
    robot = OptionsBehaviour(layout)
    robot.start(0.0, 10.0)
    to = [np.eye(3)[j] * 2 - 2 / 3 for j in range(3)]
    assert robot.step(0.01, np.zeros(3), None, (0.5, 0.7)).action == "idle"  # no leader yet
    first = robot.step(0.02, to[2], None, (0.5, 0.7))
    assert first == OptionsCommand("move", 2, "first leading option")
    for k in range(3):  # three samples toward 0: not yet (C_max = 4)
        assert robot.step(0.03 + 0.01 * k, to[0], None, (0.6, 0.5)).target == 2
    assert robot.step(0.06, to[0], None, (0.6, 0.5)).action == "stop"
    assert robot.step(0.10, to[0], None, (0.6, 0.5)).action == "stop"  # pausing 0.1 s
    assert robot.step(0.17, to[0], None, (0.6, 0.5)) == OptionsCommand("move", 0, "pause over")
    press = robot.step(0.5, to[0], 1, layout.boxes[1].center)  # the human pressed box 1
    assert (press.action, press.target) == ("press", 1)  # the arm was at box 1: it presses it
    assert robot.step(0.6, to[2], None, (0.0, 0.0)) == press  # final


def test_nearest_and_pressed_over_n_boxes() -> None:
    layout = OptionsLayout.row(4)
    for j, box in enumerate(layout.boxes):
        assert layout.nearest(box.center) == j
        assert layout.pressed([(0.5, 0.9), box.center]) == j
    assert layout.pressed([(0.5, 0.9)]) is None
    mid = (0.5 * (layout.boxes[1].center[0] + layout.boxes[2].center[0]), 0.5)
    assert layout.nearest(mid) == 1  # a tie goes to the lower index, as red wins today's
    with pytest.raises(ValueError, match="needs a target box"):
        OptionsCommand("move")
