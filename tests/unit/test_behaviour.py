"""Algorithm 2 (SPEC §4): the robot's behaviour state machine, the paper's and over N boxes."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from services.model.behaviour import (
    TIE_TOLERANCE,
    ArmCommand,
    BehaviourParams,
    OptionsBehaviour,
    OptionsCommand,
    RobotBehaviour,
    leader_or_nearest_tie,
)
from services.model.debounce import DebounceParams
from services.model.dynamics import leading_option
from services.model.geometry import Colour, OptionsLayout, TableLayout

LAYOUT = TableLayout()
HOME = (0.5, 0.08)
NEAR_RED = LAYOUT.red.center
NEAR_BLUE = LAYOUT.blue.center
DT = 0.01


def ref_debounced(samples: list[int], c_max: int) -> int:
    """Reference: run-length encode the non-zero signs; a run against the state of length
    >= c_max flips the state. (Independent of the state machine's per-sample counter.)"""
    signs = [s for s in samples if s != 0]
    if not signs:
        return 0
    runs: list[list[int]] = []
    for s in signs:
        if runs and runs[-1][0] == s:
            runs[-1][1] += 1
        else:
            runs.append([s, 1])
    state = runs[0][0]
    for s, n in runs[1:]:
        if s != state and n >= c_max:
            state = s
    return state


def started(
    params: BehaviourParams | None = None,
    t0: float = 0.0,
    *,
    c_max: int | None = None,
    timeout_s: float = 10.0,
) -> RobotBehaviour:
    debounce = DebounceParams(c_max) if c_max is not None else None
    b = RobotBehaviour(LAYOUT, params, debounce)
    b.start(t0, timeout_s)
    return b


@pytest.mark.parametrize(
    "make",
    [
        lambda: DebounceParams(c_max=0),
        lambda: BehaviourParams(pause_s=-0.1),
        lambda: RobotBehaviour(LAYOUT).start(0.0, timeout_s=0),
        lambda: RobotBehaviour(LAYOUT).start(0.0, timeout_s=float("nan")),
    ],
    ids=["c_max 0", "pause < 0", "timeout 0", "timeout nan"],
)
def test_params_validation(make: Callable[[], object]) -> None:
    with pytest.raises(ValueError):
        make()


def test_the_default_pause_is_100_ms() -> None:
    assert BehaviourParams() == BehaviourParams(pause_s=0.1)


def test_default_c_max_is_four_consecutive_samples() -> None:
    # SPEC §4: C_max = 4. Three opposite samples never turn the robot; the fourth does.
    b = started()
    t = 0.0
    b.step(t, 1.0, None, HOME)
    for _ in range(3):
        t += DT
        b.step(t, -1.0, None, HOME)
    assert b.direction == 1
    t += DT
    b.step(t, -1.0, None, HOME)
    assert b.direction == -1


def test_arm_command_validation() -> None:
    assert ArmCommand.move(1).target == "red"
    assert ArmCommand.move(-1).target == "blue"
    assert ArmCommand.press("blue").direction == -1
    with pytest.raises(ValueError):
        ArmCommand("move", 0, None)
    with pytest.raises(ValueError):
        ArmCommand("move", 1, "blue")
    with pytest.raises(ValueError):
        ArmCommand("stop", 1, None)
    with pytest.raises(ValueError):
        ArmCommand("press", 0, None)
    with pytest.raises(ValueError):
        ArmCommand("jump")  # type: ignore[arg-type]


def test_idle_before_go_and_waiting_until_nonzero() -> None:
    b = RobotBehaviour(LAYOUT)
    assert b.step(0.0, 1.0, None, HOME).action == "idle"
    assert b.phase == "idle"
    b.start(0.1, 10.0)
    assert b.phase == "waiting"
    assert b.step(0.2, None, None, HOME).action == "idle"
    assert b.step(0.3, 0.0, None, HOME).action == "idle"
    cmd = b.step(0.4, -0.2, None, HOME)
    assert cmd == ArmCommand.move(-1, cmd.reason)
    assert b.phase == "moving" and b.direction == -1


def test_start_twice_needs_reset() -> None:
    b = started()
    with pytest.raises(RuntimeError):
        b.start(1.0, 10.0)
    b.reset()
    b.start(2.0, 10.0)
    assert b.t_go == 2.0


def test_reversal_needs_c_max_samples_then_pause_then_move() -> None:
    b = started(BehaviourParams(pause_s=0.1), c_max=4)
    t = 0.0
    assert b.step(t, 1.0, None, HOME).action == "move"
    for _ in range(3):
        t += DT
        assert b.step(t, -1.0, None, HOME) == ArmCommand.move(1, "continue")
    t += DT
    cmd = b.step(t, -1.0, None, HOME)
    assert cmd.action == "stop" and b.phase == "pausing" and b.direction == -1
    t_confirm = t
    actions = []
    while True:
        t += DT
        cmd = b.step(t, -1.0, None, HOME)
        actions.append((t, cmd.action))
        if cmd.action == "move":
            break
    assert cmd.direction == -1
    assert all(a == "stop" for _, a in actions[:-1])
    assert actions[-1][0] - t_confirm == pytest.approx(0.1, abs=DT + 1e-9)
    assert all(tt - t_confirm < 0.1 for tt, _ in actions[:-1])


def test_interrupted_flip_resets_the_count() -> None:
    b = started(c_max=3)
    t = 0.0
    b.step(t, 1.0, None, HOME)
    for z in (-1, -1, 1, -1, -1, 0, 1, -1, -1):
        t += DT
        assert b.step(t, z, None, HOME).action == "move"
        assert b.direction == 1
    # Without the reset, the fourth -1 (fifth sample) would have confirmed; now the third
    # consecutive -1 after the last +1 does.
    t += DT
    assert b.step(t, -1.0, None, HOME).action == "stop"
    assert b.direction == -1


def test_zero_samples_neither_count_nor_break() -> None:
    b = started(c_max=3)
    t = 0.0
    b.step(t, 1.0, None, HOME)
    for z in (-1, 0, None, -1, 0):
        t += DT
        b.step(t, z, None, HOME)
    assert b.direction == 1
    t += DT
    assert b.step(t, -1.0, None, HOME).action == "stop"
    assert b.direction == -1


@settings(max_examples=200, deadline=None)
@given(
    first=st.sampled_from([1, -1]),
    c_max=st.integers(1, 6),
    blocks=st.lists(st.tuples(st.integers(1, 6), st.integers(0, 3)), max_size=20),
)
def test_flips_shorter_than_c_max_never_change_direction(
    first: int, c_max: int, blocks: list[tuple[int, int]]
) -> None:
    b = started(c_max=c_max)
    t = 0.0
    assert b.step(t, float(first), None, HOME).direction == first
    for flip_len, zeros in blocks:
        flip = min(flip_len, c_max - 1)  # strictly shorter than c_max
        seq = [-first] * flip + [0] * zeros + [first]
        for s in seq:
            t += DT
            cmd = b.step(t, float(s), None, HOME)
            assert cmd == ArmCommand.move(first, cmd.reason)
            assert b.direction == first


@settings(max_examples=300, deadline=None)
@given(
    c_max=st.integers(1, 5),
    pause_s=st.sampled_from([0.0, 0.02, 0.1]),
    samples=st.lists(st.sampled_from([1, -1, 0, None]), max_size=80),
)
def test_direction_always_equals_the_debounced_sign(
    c_max: int, pause_s: float, samples: list[int | None]
) -> None:
    b = started(BehaviourParams(pause_s=pause_s), c_max=c_max)
    seen: list[int] = []
    for k, s in enumerate(samples):
        t = (k + 1) * DT
        cmd = b.step(t, None if s is None else float(s), None, HOME)
        seen.append(0 if s is None else s)
        expected = ref_debounced(seen, c_max)
        assert b.direction == expected
        if cmd.action == "move":
            assert cmd.direction == expected
        # Never moves against the debounced sign, never moves before a sign exists.
        assert cmd.action != "move" or expected != 0


@settings(max_examples=100, deadline=None)
@given(pause_s=st.floats(0.0, 0.5), dt=st.floats(0.001, 0.05))
def test_pause_lasts_pause_s(pause_s: float, dt: float) -> None:
    b = started(BehaviourParams(pause_s=pause_s), c_max=1)
    b.step(0.0, 1.0, None, HOME)
    t_confirm = dt
    assert b.step(t_confirm, -1.0, None, HOME).action == "stop"
    k = 1
    while True:
        t = t_confirm + k * dt
        cmd = b.step(t, -1.0, None, HOME)
        if cmd.action == "move":
            assert t >= t_confirm + pause_s
            assert t < t_confirm + pause_s + dt + 1e-9
            break
        assert cmd.action == "stop"
        assert t < t_confirm + pause_s
        k += 1


def test_flip_back_during_pause_restarts_pause_toward_the_new_side() -> None:
    b = started(BehaviourParams(pause_s=1.0), c_max=2)
    b.step(0.0, 1.0, None, HOME)
    b.step(0.1, -1.0, None, HOME)
    assert b.step(0.2, -1.0, None, HOME).action == "stop"
    b.step(0.3, 1.0, None, HOME)
    assert b.step(0.4, 1.0, None, HOME).action == "stop"  # confirmed back to red
    assert b.direction == 1
    assert b.step(1.3, 1.0, None, HOME).action == "stop"  # pause restarted at 0.4
    assert b.step(1.4, 1.0, None, HOME) == ArmCommand.move(1, "pause over")


@pytest.mark.parametrize(
    ("ee", "expected"), [(NEAR_RED, "red"), (NEAR_BLUE, "blue"), ((0.9, 0.5), "red")]
)
def test_human_press_stops_and_presses_nearest(ee: tuple[float, float], expected: str) -> None:
    b = started()
    b.step(0.0, -1.0, None, HOME)  # heading blue: the nearest box still decides
    cmd = b.step(0.5, -1.0, "red", ee)
    assert cmd.action == "press" and cmd.target == expected == LAYOUT.nearest(ee)
    assert b.ended and b.pressed_colour == expected and b.phase == "pressing"
    # Further inputs change nothing.
    again = b.step(0.6, 5.0, None, (0.0, 0.0))
    assert again == cmd
    b.complete()
    assert b.phase == "done" and b.ended
    assert b.step(0.7, -5.0, "blue", HOME) == cmd


@settings(max_examples=100, deadline=None)
@given(x=st.floats(0.0, 1.0), y=st.floats(0.0, 1.0))
def test_press_always_targets_the_nearest_box(x: float, y: float) -> None:
    b = started()
    cmd = b.step(0.1, 1.0, "blue", (x, y))
    assert cmd.action == "press" and cmd.target == LAYOUT.nearest((x, y))


def test_press_while_waiting_uses_home() -> None:
    b = started()
    cmd = b.step(0.2, None, "blue", HOME)
    assert cmd.action == "press" and cmd.target == LAYOUT.nearest(HOME)


def test_timeout_presses() -> None:
    b = started(t0=5.0, timeout_s=2.0)
    b.step(5.1, 1.0, None, HOME)
    assert b.step(6.99, 1.0, None, NEAR_BLUE).action == "move"
    cmd = b.step(7.0, 1.0, None, NEAR_BLUE)
    assert cmd == ArmCommand.press("blue", cmd.reason)
    assert "timeout" in cmd.reason


def test_timeout_even_without_any_z_r() -> None:
    b = started(timeout_s=1.0)
    assert b.step(1.0, None, None, NEAR_RED).target == "red"


def test_time_and_input_validation() -> None:
    b = started(t0=1.0)
    with pytest.raises(ValueError):
        b.step(0.5, 1.0, None, HOME)
    with pytest.raises(ValueError):
        b.step(1.5, float("nan"), None, HOME)
    with pytest.raises(ValueError):
        b.step(float("inf"), 1.0, None, HOME)


# -- the general form over N boxes, and its two-option kernel ------------------------------


def as_options(cmd: ArmCommand) -> OptionsCommand:
    target = {"red": 0, "blue": 1, None: None}[cmd.target]
    return OptionsCommand(cmd.action, target, "")


@settings(max_examples=100, deadline=None)
@given(
    st.lists(st.tuples(st.sampled_from([-1.0, 0.0, 0.5, 1.0, None]), st.booleans()),
             min_size=1, max_size=80),
    st.floats(0.2, 0.8),
    st.integers(1, 5),
)
def test_two_boxes_command_the_arm_as_the_paper(
    stream: list[tuple[float | None, bool]], x: float, c_max: int
) -> None:
    # The kernel (RobotBehaviour, z_r a number) and the general form (z_r = (x, −x)) agree.
    table, debounce = TableLayout(), DebounceParams(c_max)
    paper = RobotBehaviour(table, debounce=debounce)
    options = OptionsBehaviour(OptionsLayout.from_table(table), debounce=debounce)
    assert as_options(paper.start(0.0, 10.0)).action == options.start(0.0, 10.0).action
    ee = (x, 0.5)
    for i, (z, press) in enumerate(stream):
        t = 0.03 * (i + 1)
        pressed: Colour | None = "red" if press and i % 7 == 6 else None
        want = paper.step(t, z, pressed, ee)
        got = options.step(t, None if z is None else np.array([z, -z]),
                           None if pressed is None else 0, ee)
        assert (got.action, got.target) == (as_options(want).action, as_options(want).target)
        assert options.phase == paper.phase and options.heading == paper.heading
        assert options.pressed_option == {"red": 0, "blue": 1, None: None}[paper.pressed_colour]


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
    assert robot.pressed_option == 1 and robot.ended
    assert robot.step(0.6, to[2], None, (0.0, 0.0)) == press  # final


@pytest.mark.parametrize("n", [2, 3, 5])
def test_a_non_finite_z_r_is_refused_for_any_n(n: int) -> None:
    robot = OptionsBehaviour(OptionsLayout.row(n))
    robot.start(0.0, 10.0)
    z = np.zeros(n)
    z[-1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        robot.step(0.1, z, None, HOME)


def test_nearest_and_pressed_over_n_boxes() -> None:
    layout = OptionsLayout.row(4)
    for j, box in enumerate(layout.boxes):
        assert layout.nearest(box.center) == j
        assert layout.pressed([(0.5, 0.9), box.center]) == j
    assert layout.pressed([(0.5, 0.9)]) is None
    mid = (0.5 * (layout.boxes[1].center[0] + layout.boxes[2].center[0]), 0.5)
    assert layout.nearest(mid) == 1  # a tie goes to the lower index, as red wins the paper's
    with pytest.raises(ValueError, match="needs a target box"):
        OptionsCommand("move")


# --- the tie rule of a dissensus robot over N boxes

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
