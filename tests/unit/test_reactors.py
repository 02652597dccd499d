"""The two reactors every runner shares: the robot's trial (Algorithm 2 with its events) and the
trial judge (the human's press, ẑ_h, the verdict), and the offline loop's interrupted trials."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.arm import OptionsSimArm
from services.model.behaviour import (
    BehaviourParams,
)
from services.model.closed_loop import run_offline_session
from services.model.debounce import DebounceParams
from services.model.decision import rk4_robot
from services.model.dynamics import OptionsParams, option_vector
from services.model.geometry import OptionsLayout
from services.model.judge import TrialJudge
from services.model.params import NodConfig
from services.model.protocol import TrialEnd
from services.model.robot import OptionsRobotTrial, RobotTrial
from services.model.schedule import OptionsSchedule

CFG = NodConfig()
LAYOUT = CFG.layout
RED_IN = LAYOUT.box("red").center  # a landmark inside the red box
BLUE_IN = LAYOUT.box("blue").center
AWAY = (0.5, 0.9)  # the hand at rest, in no box


def robot() -> RobotTrial:
    return RobotTrial(LAYOUT, CFG.behaviour, CFG.debounce, CFG.protocol.trial_timeout_s)


def test_the_robot_idles_until_go_and_sees_the_press_only_after_it():
    r = robot()
    r.setup(1)
    assert r.step(0.0, 0.5, (0.5, 0.1)) is None  # no trial runs before "go"
    assert r.see_hand([RED_IN]) is None  # a hand in a box before "go" is no press
    r.go(1.0)
    assert r.step(1.1, 0.5, (0.5, 0.1)).action == "move"
    assert r.see_hand([AWAY]) is None
    assert r.see_hand([BLUE_IN]) == "blue" and r.see_hand([RED_IN]) == "blue"  # the first
    cmd = r.step(1.2, 0.5, LAYOUT.box("red").center)
    assert cmd.action == "press" and cmd.target == "red"  # the buzzer nearest the arm


def test_the_robots_press_counts_once_and_a_new_trial_forgets_everything():
    r = robot()
    r.setup(1)
    assert not r.arm_pressed("red")  # a press before "go" is not the robot's choice
    r.go(0.0)
    assert r.arm_pressed("red") and not r.arm_pressed("red") and r.pressed == "red"
    r.setup(2)
    assert r.trial == 2 and r.pressed is None and r.human is None and not r.running


def test_an_interrupted_trial_forgets_its_moves():
    r = robot()
    r.setup(3)
    r.go(0.0)
    r.step(0.1, -0.4, (0.5, 0.1))
    assert r.running
    r.interrupted()
    assert not r.running and r.step(0.2, -0.4, (0.5, 0.1)) is None


def test_the_judge_counts_z_hat_until_the_press_and_a_late_press_is_not_the_persons():
    j = TrialJudge(CFG, LAYOUT)
    for i, z in enumerate((0.3, 0.3, 0.3)):
        j.observe(z, AWAY, t=float(i))
    assert j.see_hand([RED_IN], t=2.0) == "red" and j.t_press == 2.0
    for i, z in enumerate((-0.5,) * 10):  # after the press: never counted
        j.observe(z, AWAY, t=3.0 + i)
    assert j.tracker.switches == 0
    v = j.verdict(TrialEnd(True, True, 5.0), "red", 10)
    assert (v.human, v.robot, v.outcome, v.score) == ("red", "red", "C", 2)
    late = j.verdict(TrialEnd(False, True, 5.0), "red", 10)  # pressed after the timeout
    assert late.human is None and late.outcome is None


def test_the_press_poses_own_z_hat_counts_and_nothing_after_it():
    # ẑ_h counts "between go and the press" (SPEC §6) inclusive: the decision service stamps
    # ẑ_h with its pose's time, so the press pose's ẑ_h arrives after the press with t == t_press.
    # Here it is the 4th (c_max) sample of blue: it confirms a switch, so the trial is CH.
    def judge_with_last(t_last: float) -> TrialJudge:
        j = TrialJudge(CFG, LAYOUT)
        for i, z in enumerate((0.9,) * 4 + (-0.9,) * 3):  # beyond the switch dead band
            j.observe(z, AWAY, t=0.1 * i)
        assert j.see_hand([BLUE_IN], t=0.7) == "blue" and j.t_press == 0.7
        j.observe(-0.9, AWAY, t=t_last)
        return j

    at_press = judge_with_last(0.7)
    assert at_press.tracker.samples == 8 and at_press.tracker.switches == 1
    v = at_press.verdict(TrialEnd(True, True, 1.0), "blue", 10)
    assert (v.human, v.outcome, v.switches) == ("blue", "CH", 1)
    just_after = judge_with_last(0.7 + 1e-9)  # any later sample is not counted
    assert just_after.tracker.samples == 7 and just_after.tracker.switches == 0
    assert just_after.verdict(TrialEnd(True, True, 1.0), "blue", 10).outcome == "C"


def test_a_void_trial_has_no_presses_no_class_no_points():
    v = TrialJudge.void()
    assert (v.human, v.robot, v.outcome, v.switches, v.violations, v.score) == (
        None, None, None, 0, 0, 0)


def _schedule(n_options: int) -> OptionsSchedule | None:
    """The paper's study at two options (its kernel), the default schedule of N otherwise."""
    return None if n_options == 2 else OptionsSchedule.default(n_options)


@pytest.mark.parametrize("n_options", [2, 3])
def test_the_offline_loop_interrupts_repeats_and_gives_up_like_the_conductor(n_options):
    schedule = _schedule(n_options)
    trials = run_offline_session(CFG, 4, breaks={(2, 1): 1.0, (5, 1): 2.0}, schedule=schedule)
    by = {t.trial: t for t in trials}
    assert sorted(by) == list(range(1, 9))
    assert by[2].attempts == 2 and by[5].attempts == 2 and by[1].attempts == 1
    assert not any(t.interrupted for t in trials)
    # Out of attempts: stored interrupted, never classified or scored, and the session goes on.
    cfg = replace(CFG, protocol=replace(CFG.protocol, max_attempts=2))
    gave_up = run_offline_session(cfg, 4, breaks={(3, 1): 0.5, (3, 2): 0.5}, schedule=schedule)
    third = [t for t in gave_up if t.trial == 3]
    assert len(third) == 1 and third[0].interrupted and third[0].attempts == 2
    assert third[0].outcome is None and third[0].score == 0
    assert [t.trial for t in gave_up] == list(range(1, 9))


@pytest.mark.parametrize("n_options", [2, 3])
def test_without_breaks_the_loop_is_the_same_session(n_options):
    schedule = _schedule(n_options)
    assert run_offline_session(CFG, 6, schedule=schedule) == run_offline_session(
        CFG, 6, breaks={}, schedule=schedule)


def test_a_replayed_hand_is_where_the_recording_was_after_go():
    from services.model.replayed_hand import ReplayedHand

    hand = ReplayedHand({
        1: [(-0.5, [(0.5, 0.9)]), (0.0, [(0.5, 0.8)]), (0.2, [(0.4, 0.5)])],
        2: [(0.1, [(0.6, 0.4)])],
    })
    hand.new_trial(None)
    hand.advance(10.0)
    assert hand.landmarks().tolist() == [[0.5, 0.9]]  # before "go": its first pose
    hand.go(10.0)
    hand.advance(10.1)
    assert hand.landmarks().tolist() == [[0.5, 0.8]]  # the latest pose at or before go + 0.1
    hand.advance(11.0)
    assert hand.landmarks().tolist() == [[0.4, 0.5]]
    hand.new_trial("red")
    hand.go(20.0)
    hand.advance(20.0)
    assert hand.landmarks().tolist() == [[0.6, 0.4]]  # before its first pose: that pose
    try:
        hand.new_trial(None)
    except ValueError as exc:
        assert "only 2 trial" in str(exc)
    else:
        raise AssertionError("a third trial out of a two-trial recording")


# -- the reactor over N boxes: on the paper's table the general robot is the paper's -----------

TWO = OptionsLayout.from_table(LAYOUT)  # option 0 is red
INDEX = {"red": 0, "blue": 1, None: None}
events = st.lists(
    st.one_of(
        st.tuples(st.just("z"), st.sampled_from([-1.0, -0.3, 0.0, 0.2, 1.0, None])),
        st.tuples(st.just("hand"), st.sampled_from(["red", "blue", "away"])),
        st.tuples(st.just("arm"), st.sampled_from(["red", "blue"])),
        st.tuples(st.sampled_from(["go", "setup", "void"]), st.none()),
    ),
    min_size=1, max_size=60,
)


@settings(max_examples=150, deadline=None)
@given(events, st.floats(0.2, 0.8))
def test_two_boxes_the_general_robot_is_the_papers(
    stream: list[tuple[str, object]], x: float
) -> None:
    """`OptionsRobotTrial` on the paper's table and `RobotTrial` (its two-option kernel) give the
    same commands (action, box), phases, human presses and robot presses, event for event."""
    paper = robot()
    general = OptionsRobotTrial(TWO, CFG.behaviour, CFG.debounce, CFG.protocol.trial_timeout_s)
    ee, where = (x, 0.5), {"red": RED_IN, "blue": BLUE_IN, "away": AWAY}
    for i, (kind, value) in enumerate(stream):
        t = 0.03 * (i + 1)
        if kind == "z":
            z = None if value is None else float(str(value))
            a = paper.step(t, z, ee)
            b = general.step(t, None if z is None else np.array([z, -z]), ee)
            assert (a is None) == (b is None)
            if a is not None and b is not None:
                assert (b.action, b.target) == (a.action, INDEX[a.target])
        elif kind == "hand":
            landmarks = [where[str(value)]]
            assert INDEX[paper.see_hand(landmarks)] == general.see_hand(landmarks)
        elif kind == "arm":
            colour = "red" if value == "red" else "blue"
            assert paper.arm_pressed(colour) == general.arm_pressed(INDEX[colour])
        elif kind == "go":
            if paper.running:
                continue  # Algorithm 2 starts once a trial
            a, b = paper.go(t), general.go(t)
            assert (b.action, b.target) == (a.action, INDEX[a.target])
        elif kind == "setup":
            paper.setup(i)
            general.setup(i)
        else:
            paper.interrupted()
            general.interrupted()
        assert general.machine.phase == paper.machine.phase
        assert (general.running, general.pressed) == (paper.running, INDEX[paper.pressed])


# --- a dissensus robot over three boxes

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
