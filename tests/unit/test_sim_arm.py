"""The kinematic simulated arm and the ArmDriver interface."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.arm import ArmDriver, OptionsSimArm, SimArm
from services.model.arm_kinematics import ArmNotConnectedError, SimArmParams
from services.model.behaviour import (
    ArmCommand,
    BehaviourParams,
    OptionsCommand,
    RobotBehaviour,
)
from services.model.geometry import OptionsLayout, TableLayout

LAYOUT = TableLayout()
P = SimArmParams()
EPS = 1e-9


def arm(params: SimArmParams = P) -> SimArm:
    a = SimArm(LAYOUT, params)
    a.connect()
    return a


def run(a: SimArm, until: float, dt: float = 0.01) -> list[tuple[float, tuple[float, float]]]:
    """Advance in steps of dt, checking the speed limit at every step; return the path."""
    path = [(a.t, a.position)]
    while a.t < until - 1e-12:
        t = min(until, a.t + dt)
        prev_t, prev_p = a.t, a.position
        a.advance(t)
        assert a.speed <= a.params.max_speed + EPS
        assert math.dist(prev_p, a.position) <= a.params.max_speed * (t - prev_t) + 1e-6
        path.append((t, a.position))
    return path


@pytest.mark.parametrize(
    "bad",
    [{"max_speed": 0}, {"max_accel": -1}, {"press_duration_s": -0.1}, {"home": (math.nan, 0.0)}],
    ids=str,
)
def test_params_validation(bad: dict[str, Any]) -> None:
    with pytest.raises(ValueError):
        SimArmParams(**bad)


def test_not_connected_raises_and_context_manager_holds() -> None:
    a = SimArm(LAYOUT)
    assert isinstance(a, ArmDriver)
    with pytest.raises(ArmNotConnectedError):
        a.send(ArmCommand.move(1))
    with pytest.raises(ArmNotConnectedError):
        a.state(0.0)
    with a as driver:
        assert driver.is_connected
        driver.send(ArmCommand.move(1))
        a.advance(0.5)
        assert a.speed > 0
    assert not a.is_connected
    # The exit held the arm: once reconnected and integrated, it comes to rest.
    a.connect()
    a.advance(2.0)
    assert a.speed == 0.0
    assert a.state(2.0).target is None


def test_starts_at_home_at_rest() -> None:
    a = arm()
    s = a.state(0.0)
    assert s.ee == (0.5, 0.08) and not s.moving and s.pressed is None and s.fault is None


def test_move_reaches_box_centre_within_limits() -> None:
    a = arm()
    assert a.send(ArmCommand.move(1)) == ArmCommand.move(1)
    run(a, 3.0)
    s = a.state(3.0)
    assert s.ee == LAYOUT.red.center and not s.moving and s.target == "red"
    assert s.pressed is None  # a move never presses


def test_cruise_speed_is_reached_but_not_exceeded() -> None:
    a = arm()
    a.send(ArmCommand.move(-1))
    speeds = []
    for k in range(1, 80):
        a.advance(k * 0.01)
        speeds.append(a.speed)
    assert max(speeds) == pytest.approx(P.max_speed, rel=1e-6)
    assert max(speeds) <= P.max_speed + EPS


def test_stop_brakes_at_bounded_deceleration() -> None:
    a = arm()
    a.send(ArmCommand.move(1))
    a.advance(0.5)
    v0 = a.speed
    p0 = a.position
    a.send(ArmCommand.stop("test"))
    prev = v0
    t = 0.5
    while a.speed > 0:
        t += 0.005
        a.advance(t)
        assert prev - a.speed <= P.max_accel * 0.005 + EPS  # no faster than max_accel
        prev = a.speed
    assert t - 0.5 == pytest.approx(v0 / P.max_accel, abs=0.01)
    assert math.dist(p0, a.position) == pytest.approx(v0**2 / (2 * P.max_accel), abs=0.003)
    rest = a.position
    a.advance(t + 1.0)
    assert a.position == rest


@settings(max_examples=60, deadline=None)
@given(
    steps=st.lists(
        st.tuples(
            st.sampled_from(["red", "blue", "stop", "press_red", "press_blue", "idle"]),
            st.floats(0.001, 0.4),
        ),
        min_size=1,
        max_size=15,
    )
)
def test_speed_and_acceleration_limits_hold_under_any_commands(
    steps: list[tuple[str, float]],
) -> None:
    a = arm()
    cmds = {
        "red": ArmCommand.move(1),
        "blue": ArmCommand.move(-1),
        "stop": ArmCommand.stop(),
        "press_red": ArmCommand.press("red"),
        "press_blue": ArmCommand.press("blue"),
        "idle": ArmCommand.idle(),
    }
    for name, duration in steps:
        a.send(cmds[name])
        end = a.t + duration
        while a.t < end - 1e-12:
            t = min(end, a.t + 0.004)
            dt = t - a.t
            v_prev, p_prev = a.velocity, a.position
            a.advance(t)
            assert a.speed <= P.max_speed + EPS
            dv = math.dist(v_prev, a.velocity)
            assert dv <= P.max_accel * dt + 1e-6
            assert math.dist(p_prev, a.position) <= P.max_speed * dt + 1e-6
            assert 0.0 <= a.position[0] <= 1.0 and 0.0 <= a.position[1] <= 1.0


def test_press_reaches_box_then_holds_press_duration() -> None:
    a = arm()
    a.send(ArmCommand.press("blue"))
    t = 0.0
    arrived = None
    while a.state(t).pressed is None:
        if arrived is None and a.position == LAYOUT.blue.center:
            arrived = t
        t += 0.01
        assert t < 5.0
    assert arrived is not None
    assert t - arrived == pytest.approx(P.press_duration_s, abs=0.011)
    s = a.state(t)
    assert s.pressed == "blue" and LAYOUT.blue.contains(s.ee)


def test_committed_press_refuses_moves_and_other_press_until_home() -> None:
    a = arm()
    a.send(ArmCommand.press("red"))
    applied = a.send(ArmCommand.move(-1))
    assert applied.action == "press" and applied.target == "red"
    assert a.send(ArmCommand.press("blue")).target == "red"
    run(a, 3.0)
    assert a.state(3.0).pressed == "red"
    a.home()
    run(a, 6.0)
    s = a.state(6.0)
    assert s.ee == P.home and s.pressed is None and s.target is None
    assert a.send(ArmCommand.move(-1)) == ArmCommand.move(-1)


def test_stop_cancels_an_unfinished_press() -> None:
    a = arm()
    a.send(ArmCommand.press("red"))
    a.advance(0.2)
    a.send(ArmCommand.stop())
    run(a, 3.0, dt=0.05)
    assert a.state(3.0).pressed is None
    assert a.send(ArmCommand.move(-1)).action == "move"


def test_fault_refuses_motion_until_cleared() -> None:
    a = arm()
    a.send(ArmCommand.move(1))
    a.advance(0.3)
    a.inject_fault("overcurrent")
    applied = a.send(ArmCommand.move(-1))
    assert applied.action == "stop" and "overcurrent" in applied.reason
    assert a.home().action == "stop"
    run(a, 1.5)
    s = a.state(1.5)
    assert s.fault == "overcurrent" and not s.moving
    a.clear_fault()
    assert a.send(ArmCommand.move(-1)).action == "move"


def test_time_validation() -> None:
    a = arm()
    a.advance(1.0)
    with pytest.raises(ValueError):
        a.advance(0.5)
    with pytest.raises(ValueError):
        a.advance(float("nan"))


def drive(
    z_r_of_t, human_press_at: float | None, until: float = 12.0, dt: float = 0.01
) -> tuple[RobotBehaviour, SimArm, list[tuple[float, tuple[float, float], str]]]:
    """Close the loop: behaviour → sim arm, as the actuation service would."""
    beh = RobotBehaviour(LAYOUT, BehaviourParams())
    a = arm()
    beh.start(0.0, timeout_s=10.0)
    trace = []
    t = 0.0
    while t <= until:
        a.advance(t)
        pressed = "red" if human_press_at is not None and t >= human_press_at else None
        cmd = beh.step(t, z_r_of_t(t), pressed, a.position)
        a.send(cmd)
        state = a.state(t)
        if state.pressed is not None:
            beh.complete()
        trace.append((t, a.position, cmd.action))
        if beh.phase == "done":
            break
        t = round(t + dt, 10)
    return beh, a, trace


def test_stop_pause_reverse_mid_path() -> None:
    beh, a, trace = drive(lambda t: 1.0 if t < 0.4 else -1.0, human_press_at=3.0)
    xs = [p[0] for _, p, _ in trace]
    i_turn = max(range(len(xs)), key=lambda i: xs[i])
    assert xs[i_turn] > 0.5  # went toward red first
    assert xs[-1] < xs[i_turn]  # then came back toward blue
    stops = [t for t, _, action in trace if action == "stop"]
    assert stops and min(stops) == pytest.approx(0.43, abs=1e-9)  # 4th sample of -1
    assert max(stops) - min(stops) == pytest.approx(0.09, abs=1e-9)  # pause 0.1 s at 10 ms
    assert beh.phase == "done"
    s = a.state(a.t)
    assert s.pressed == beh.pressed_colour


@settings(max_examples=25, deadline=None)
@given(
    first=st.sampled_from([1.0, -1.0]),
    switch_at=st.floats(0.05, 3.0),
    press_at=st.floats(0.0, 4.0),
)
def test_press_ends_in_the_box_nearest_at_decision(
    first: float, switch_at: float, press_at: float
) -> None:
    ee_at_press: list[tuple[float, float]] = []

    def z(t: float) -> float:
        return first if t < switch_at else -first

    beh = RobotBehaviour(LAYOUT)
    a = arm()
    beh.start(0.0, timeout_s=10.0)
    t = 0.0
    while beh.phase != "done":
        a.advance(t)
        pressed = "blue" if t >= press_at else None
        cmd = beh.step(t, z(t), pressed, a.position)
        if cmd.action == "press" and not ee_at_press:
            ee_at_press.append(a.position)
        a.send(cmd)
        if a.state(t).pressed is not None:
            beh.complete()
        t = round(t + 0.01, 10)
        assert t < 10.0
    expected = LAYOUT.nearest(ee_at_press[0])
    s = a.state(t)
    assert beh.pressed_colour == expected == s.pressed
    assert LAYOUT.box(expected).contains(s.ee)


def test_timeout_press_in_closed_loop() -> None:
    beh, a, _ = drive(lambda t: -1.0, human_press_at=None, until=15.0)
    assert beh.phase == "done" and beh.pressed_colour == "blue"
    assert a.state(a.t).pressed == "blue"


# --- the arm over N boxes, the paper's SimArm its two-box kernel

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
