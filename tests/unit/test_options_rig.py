"""The N_o-option rig's pure parts: arm, gaze, tie rule, judge."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from services.model.arm import OptionsSimArm, SimArm
from services.model.behaviour import (
    TIE_TOLERANCE,
    ArmCommand,
    BehaviourParams,
    OptionsCommand,
    leader_or_nearest_tie,
)
from services.model.debounce import DebounceParams
from services.model.decision import rk4_robot
from services.model.dynamics import OptionsParams, leading_option, option_vector
from services.model.gaze import GAZE_LEVEL_NAMES, cue_strength, gaze_toward, read_gaze
from services.model.geometry import CommitLine, OptionsLayout, TableLayout
from services.model.outcome import OptionsOutcomeTracker, OutcomeTracker
from services.model.robot import OptionsRobotTrial

opinions = st.floats(-2.0, 2.0, allow_nan=False)


def test_a_dissensus_tie_goes_to_the_nearest_tied_box() -> None:
    layout = OptionsLayout.row(3)
    # the human on box 1 (the middle): the robot ties boxes 0 and 2 up to rounding
    z = np.array([0.3, -0.6, 0.3 + 1e-16])
    assert leading_option(z) == 2  # the ulp alone would pick box 2
    assert leader_or_nearest_tie(z, layout, layout.boxes[0].center) == 0
    assert leader_or_nearest_tie(z, layout, layout.boxes[2].center) == 2
    assert leader_or_nearest_tie(z, layout, (0.5, 0.08)) == 0  # midway: the lower index
    assert leader_or_nearest_tie(np.zeros(3), layout, (0.5, 0.08)) is None
    assert leader_or_nearest_tie(np.array([0.1, 0.3, -0.4]), layout, (0.9, 0.2)) == 1


@example(x=TIE_TOLERANCE, ex=0.0)  # the two are 2e-9 apart: a leader (hypothesis found it)
@example(x=TIE_TOLERANCE / 2, ex=0.0)  # exactly the tolerance apart: a tie
@given(st.floats(-3, 3, allow_nan=False), st.floats(0.0, 1.0))
def test_two_boxes_tie_rule_is_the_sign_outside_the_tolerance(x: float, ex: float) -> None:
    layout = OptionsLayout.from_table(TableLayout())
    z = np.array([x, -x])
    got = leader_or_nearest_tie(z, layout, (ex, 0.2))
    # A tie is two values within the tolerance of each other: here |x - (-x)| = 2|x|.
    if 2 * abs(x) > TIE_TOLERANCE:
        assert got == leading_option(z)
    else:
        assert got is None


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["move", "press", "stop", "idle", "home", "fault",
                                           "clear"]),
                          st.sampled_from(["red", "blue"]), st.floats(0.01, 0.4)),
                min_size=1, max_size=16))
def test_two_box_options_arm_moves_as_the_paper_arm(
    cmds: list[tuple[str, str, float]]
) -> None:
    """The general arm on the paper's table is the paper's `SimArm` (its two-option kernel):
    the same applied commands (action, box, reason) and the same states, bit for bit."""
    table = TableLayout()
    paper, options = SimArm(table), OptionsSimArm(OptionsLayout.from_table(table))
    paper.connect()
    options.connect()
    index = {"red": 0, "blue": 1, None: None}
    t = 0.0
    for action, colour, dt in cmds:
        sign = 1 if colour == "red" else -1
        if action == "fault":
            paper.inject_fault("bus")
            options.inject_fault("bus")
        elif action == "clear":
            paper.clear_fault()
            options.clear_fault()
        else:
            if action == "home":
                applied_a, applied_b = paper.home(), options.home()
            else:
                if action == "move":
                    a, b = ArmCommand.move(sign), OptionsCommand("move", index[colour])
                elif action == "press":
                    a = ArmCommand.press(colour)  # type: ignore[arg-type]
                    b = OptionsCommand("press", index[colour])
                elif action == "stop":
                    a, b = ArmCommand.stop(), OptionsCommand("stop")
                else:
                    a, b = ArmCommand.idle(), OptionsCommand("idle")
                applied_a, applied_b = paper.send(a), options.send(b)
            assert (applied_b.action, applied_b.target, applied_b.reason) == (
                applied_a.action, index[applied_a.target], applied_a.reason)
        t += dt
        sa, sb = paper.state(t), options.state(t)
        assert (sb.t, sb.ee, sb.moving, sb.fault) == (sa.t, sa.ee, sa.moving, sa.fault)
        assert (sb.target, sb.pressed) == (index[sa.target], index[sa.pressed])


def test_the_options_arm_presses_any_box_and_refuses_after_a_press() -> None:
    layout = OptionsLayout.row(4)
    arm = OptionsSimArm(layout)
    arm.connect()
    arm.send(OptionsCommand("press", 2))
    assert arm.send(OptionsCommand("move", 0)) == OptionsCommand(
        "press", 2, "refused move: press already committed"
    )
    t = 0.0
    while arm.state(t).pressed is None and t < 10:
        t += 0.05
    assert arm.state(t).pressed == 2 and arm.position == layout.boxes[2].center
    arm.home()
    with pytest.raises(ValueError, match="not on this table"):
        arm.send(OptionsCommand("move", 7))


@pytest.mark.parametrize("n", [2, 3, 4, 6])
def test_the_gaze_toward_a_box_reads_back_as_that_box(n: int) -> None:
    layout = OptionsLayout.row(n)
    commands = set()
    for level in GAZE_LEVEL_NAMES:
        for j in range(n):
            gaze = gaze_toward(layout, j, level)
            option, strength = read_gaze(layout, gaze)
            if level == "neutral":
                assert (option, strength) == (None, 0.0)
                continue
            assert option == j
            assert strength == pytest.approx(cue_strength(level), abs=1e-9)
            commands.add((round(gaze.yaw, 9), round(gaze.pitch, 9)))
    assert len(commands) == n * (len(GAZE_LEVEL_NAMES) - 1)  # every cue a distinct pose


def test_the_middle_box_is_told_from_neutral_by_pitch() -> None:
    layout = OptionsLayout.row(3)
    middle = gaze_toward(layout, 1, "extreme")
    assert abs(middle.yaw) < 1e-12 and middle.pitch < -0.3
    right, left = gaze_toward(layout, 2, "low"), gaze_toward(layout, 0, "low")
    assert right.yaw > 0 > left.yaw and right.yaw == pytest.approx(-left.yaw)  # +x: red's side


samples = st.lists(
    st.tuples(st.sampled_from([-1.0, -0.3, -0.02, 0.0, 0.02, 0.4, 1.0]), st.floats(0.1, 0.9)),
    min_size=1, max_size=60,
)


@settings(max_examples=150, deadline=None)
@given(samples, st.integers(1, 5), st.sampled_from([0.0, 0.05]))
def test_two_box_switches_and_violations_are_the_papers(
    stream: list[tuple[float, float]], c_max: int, dead_band: float
) -> None:
    line = CommitLine()
    paper = OutcomeTracker(DebounceParams(c_max), line, dead_band)
    options = OptionsOutcomeTracker(DebounceParams(c_max), line, dead_band)
    for z, y in stream:
        paper.add(z, (0.5, y))
        options.add(np.array([z, -z]), (0.5, y))
        assert (options.switches, options.violations) == (paper.switches, paper.violations)


def test_three_boxes_count_a_change_of_leading_option() -> None:
    tracker = OptionsOutcomeTracker(DebounceParams(2), CommitLine(), 0.0)
    to = [0.5 * option_vector(j, 3) for j in range(3)]
    for z in [to[0], to[0], to[2], to[1], to[1], to[1], to[2], to[2]]:
        tracker.add(z, (0.5, 0.8))
    assert tracker.first == 0 and tracker.switches == 2 and tracker.violations == 1
    assert math.isclose(float(to[1][1] - to[1][0]), 1.0)


def dissensus_press(h: int, break_ties: bool) -> int | None:
    """The box a dissensus robot presses with ẑ_h held on h, stepped as the decision engine."""
    layout, p = OptionsLayout.row(3), OptionsParams(n_options=3)
    z_hat = 0.8 * option_vector(h, 3)
    arm = OptionsSimArm(layout)
    arm.connect()
    robot = OptionsRobotTrial(layout, BehaviourParams(), DebounceParams(), 3.0)
    robot.machine.break_ties = break_ties
    robot.go(0.0)
    z_r, t = np.zeros(3), 0.0
    while arm.state(t).pressed is None and t < 6.0:
        t += 1 / 30
        z_r, _ = rk4_robot(z_r, 0.0, z_hat, [0.001] * 33 + [1 / 30 - 0.033], p, None)
        cmd = robot.step(t, z_r, arm.state(t).ee)
        if cmd is not None:
            arm.send(cmd)
    return arm.state(t).pressed


def test_a_dissensus_robot_held_against_a_human_takes_the_nearest_other_box() -> None:
    """Controller off, ẑ_h held on h: z_r ties among the other two boxes (up to rounding).

    With the tie rule the robot heads for the tied box nearest its home at once; without it,
    the integrator's rounding picks one of them (here the farther one for h = 0).
    """
    layout, home = OptionsLayout.row(3), (0.5, 0.08)
    ruled, unruled = [], []
    for h in range(3):
        others = sorted(set(range(3)) - {h},
                        key=lambda j: (math.dist(home, layout.boxes[j].center), j))
        ruled.append(dissensus_press(h, True))
        unruled.append(dissensus_press(h, False))
        assert ruled[-1] == others[0]
    assert ruled == [1, 0, 1] and unruled != ruled
