"""Gaze levels, the attention gesture, and gaze → servo targets with limits (SPEC §5)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.eyes.servos import ServoDriver, ServoNotConnectedError, SimServoDriver
from services.model.gaze import (
    EYES,
    GAZE_LEVEL_NAMES,
    GAZE_LEVELS,
    AttentionGestureParams,
    GazeCommand,
    attention_gesture,
    cue_strength,
    gaze_level,
    gaze_toward,
    geometric_gaze,
    read_gaze,
    read_geometric_gaze,
)
from services.model.geometry import Box, OptionsLayout, TableLayout
from services.model.servos import (
    SERVO_NAMES,
    EyesCalibration,
    ServoCalibration,
    ServoTargets,
    enforce_limits,
    servo_targets,
)

SPEC_TABLE = {
    "neutral": (0.0, 0.0),
    "minimal": (-0.47, 0.31),
    "low": (0.53, -0.53),
    "moderate": (0.62, -0.62),
    "significant": (-0.72, 0.72),
    "extreme": (1.09, -0.94),
}

any_angle = st.floats(allow_nan=False, allow_infinity=False)
servo_cal = st.builds(
    lambda lo, span, trim, d, p0, dp: ServoCalibration(
        trim_deg=trim,
        direction=d,
        min_deg=lo,
        max_deg=min(180.0, lo + span),
        min_pulse_us=p0,
        max_pulse_us=p0 + dp,
    ),
    lo=st.floats(0.0, 170.0),
    span=st.floats(1.0, 180.0),
    trim=st.floats(-30.0, 30.0),
    d=st.sampled_from([1, -1]),
    p0=st.floats(100.0, 1000.0),
    dp=st.floats(100.0, 3000.0),
)
eyes_cal = st.builds(EyesCalibration, servo_cal, servo_cal, servo_cal, servo_cal)


def test_gaze_table_is_the_spec_table() -> None:
    assert tuple(GAZE_LEVELS) == GAZE_LEVEL_NAMES
    for name, (yaw, pitch) in SPEC_TABLE.items():
        level = gaze_level(name)
        assert (level.yaw, level.pitch) == (yaw, pitch)
        assert level.toward(level.option) == GazeCommand(yaw, pitch)
    with pytest.raises(ValueError, match="expected one of"):
        gaze_level("furious")


def test_positive_yaw_looks_toward_red_and_mirroring() -> None:
    for level in GAZE_LEVELS.values():
        if level.option is None:
            assert level.toward("red") == GazeCommand() == level.toward("blue")
            continue
        assert level.toward("red").yaw > 0 > level.toward("blue").yaw
        other = "blue" if level.option == "red" else "red"
        mirrored = level.toward(other)
        assert (mirrored.yaw, mirrored.pitch) == (-level.yaw, -level.pitch)


def test_gaze_command_rejects_non_finite() -> None:
    with pytest.raises(ValueError):
        GazeCommand(float("nan"), 0.0)
    with pytest.raises(ValueError):
        GazeCommand(0.0, float("inf"))


def test_attention_gesture_default() -> None:
    seq = attention_gesture(10.0)
    (t0, limit), (t1, settle) = seq
    assert t0 == 10.0 and t1 == pytest.approx(10.6)
    assert 0 < limit.yaw < math.pi / 2  # near the limit, toward red, inside the travel
    assert limit.yaw > 0.8 * math.pi / 2
    assert settle == GazeCommand(-0.47, 0.31)  # trial 4's minimal gaze toward blue


def test_attention_gesture_flicks_and_offsets() -> None:
    p = AttentionGestureParams(flicks=2, flick_s=0.2, hold_s=0.5)
    seq = attention_gesture(0.0, GazeCommand(0.5, -0.5), p)
    times = [t for t, _ in seq]
    assert times == sorted(times) and times[0] == 0.0
    assert times[-1] == pytest.approx(p.duration_s) == pytest.approx(1.3)
    assert seq[-1][1] == GazeCommand(0.5, -0.5)
    assert [c.yaw > 0 for _, c in seq[:-1]] == [True, False, True, False, True]
    with pytest.raises(ValueError):
        AttentionGestureParams(limit_yaw=-1.0)
    with pytest.raises(ValueError):
        AttentionGestureParams(flicks=-1)


def test_servo_calibration_validation() -> None:
    with pytest.raises(ValueError):
        ServoCalibration(direction=0)
    with pytest.raises(ValueError):
        ServoCalibration(min_deg=100, max_deg=90)
    with pytest.raises(ValueError):
        ServoCalibration(max_deg=200)
    with pytest.raises(ValueError):
        ServoCalibration(min_pulse_us=2500, max_pulse_us=500)
    with pytest.raises(ValueError):
        ServoCalibration(trim_deg=float("nan"))


def test_neutral_is_centre_and_known_values() -> None:
    t = servo_targets(GazeCommand(), EyesCalibration())
    assert t.angles_deg == (90.0,) * 4 and t.pulses_us == (1500.0,) * 4 and t.clamped == ()
    t = servo_targets(GazeCommand(math.pi / 4, -math.pi / 6), EyesCalibration())
    assert t.angles_deg == pytest.approx((135.0, 60.0, 135.0, 60.0))
    assert t.pulses_us == pytest.approx((2000.0, 1166.6667, 2000.0, 1166.6667))


def test_direction_and_trim() -> None:
    cal = EyesCalibration(
        right_pan=ServoCalibration(direction=-1, trim_deg=5.0),
        left_tilt=ServoCalibration(trim_deg=-3.0),
    )
    t = servo_targets(GazeCommand(math.radians(20), math.radians(10)), cal)
    d = t.as_dict()
    assert d["left_pan"][0] == pytest.approx(110.0)
    assert d["right_pan"][0] == pytest.approx(75.0)
    assert d["left_tilt"][0] == pytest.approx(97.0)
    assert d["right_tilt"][0] == pytest.approx(100.0)


def test_extreme_trial_gaze_fits_default_limits() -> None:
    t = servo_targets(GAZE_LEVELS["extreme"].toward("red"), EyesCalibration())
    assert t.clamped == ()
    tight = EyesCalibration(*(ServoCalibration(min_deg=45, max_deg=135),) * 4)
    t = servo_targets(GAZE_LEVELS["extreme"].toward("red"), tight)
    assert t.clamped == SERVO_NAMES and t.angles_deg == (135.0, 45.0, 135.0, 45.0)


@settings(max_examples=500)
@given(yaw=any_angle, pitch=any_angle, calib=eyes_cal)
def test_pulses_always_within_limits_and_clamp_report_exact(
    yaw: float, pitch: float, calib: EyesCalibration
) -> None:
    t = servo_targets(GazeCommand(yaw, pitch), calib)
    raws = (yaw, pitch, yaw, pitch)
    for name, g, c, angle, pulse in zip(
        SERVO_NAMES, raws, calib.servos(), t.angles_deg, t.pulses_us, strict=True
    ):
        assert c.min_deg <= angle <= c.max_deg
        lo, hi = c.pulse_limits_us
        assert lo - 1e-9 <= pulse <= hi + 1e-9
        assert c.min_pulse_us - 1e-9 <= pulse <= c.max_pulse_us + 1e-9
        raw = 90.0 + c.direction * math.degrees(g) + c.trim_deg
        out_of_limits = not (c.min_deg <= raw <= c.max_deg)
        assert (name in t.clamped) == out_of_limits
        if not out_of_limits:
            assert angle == raw
    assert bool(t.clamped) == any(
        not (c.min_deg <= 90.0 + c.direction * math.degrees(g) + c.trim_deg <= c.max_deg)
        for g, c in zip(raws, calib.servos(), strict=True)
    )


def test_huge_angles_clamp_to_the_right_side() -> None:
    t = servo_targets(GazeCommand(1e308, -1e308), EyesCalibration())
    assert t.angles_deg == (180.0, 0.0, 180.0, 0.0)
    assert t.pulses_us == (2500.0, 500.0, 2500.0, 500.0)
    assert t.clamped == SERVO_NAMES


def test_servo_targets_validation() -> None:
    with pytest.raises(ValueError):
        ServoTargets((90.0,) * 4, (1500.0, 1500.0, 1500.0, float("nan")))
    with pytest.raises(ValueError):
        ServoTargets((90.0,) * 4, (1500.0,) * 4, ("nose",))


@settings(max_examples=200)
@given(
    angles=st.tuples(*(st.floats(-1e6, 1e6),) * 4),
    pulses=st.tuples(*(st.floats(-1e6, 1e6),) * 4),
    calib=eyes_cal,
)
def test_driver_never_applies_out_of_limit_targets(
    angles: tuple[float, float, float, float],
    pulses: tuple[float, float, float, float],
    calib: EyesCalibration,
) -> None:
    drv = SimServoDriver(calib)
    drv.connect()
    applied = drv.send(ServoTargets(angles, pulses))  # hand-built, possibly inconsistent
    assert drv.last == applied
    for name, a, c, angle, pulse in zip(
        SERVO_NAMES, angles, calib.servos(), applied.angles_deg, applied.pulses_us, strict=True
    ):
        assert c.min_deg <= angle <= c.max_deg
        assert pulse == pytest.approx(c.pulse_us(angle))
        assert (name in applied.clamped) == (not c.min_deg <= a <= c.max_deg)


def test_enforce_limits_keeps_existing_report() -> None:
    cal = EyesCalibration()
    t = servo_targets(GazeCommand(10.0, 0.0), cal)
    assert enforce_limits(t, cal) == t


def test_sim_driver_lifecycle() -> None:
    drv = SimServoDriver()
    assert isinstance(drv, ServoDriver)
    with pytest.raises(ServoNotConnectedError):
        drv.neutral()
    with drv:
        applied = drv.look(GAZE_LEVELS["low"].toward("red"))
        assert applied.angles_deg[0] == pytest.approx(90 + math.degrees(0.53))
    assert not drv.is_connected
    # Leaving the block returned the eyes to neutral.
    assert drv.sent[-1].angles_deg == (90.0,) * 4
    assert len(drv.sent) == 2


# -- the gaze toward an option of N: the paper's table is the two-option kernel ---------------

two_box_tables = st.tuples(
    st.floats(0.05, 0.45), st.floats(0.55, 0.95), st.floats(0.08, 0.3), st.floats(0.08, 0.3),
    st.booleans(),
)


def _two_boxes(table: tuple[float, float, float, float, bool]) -> OptionsLayout:
    """Two boxes 0.1 wide, one each side of the eyes; option 0 on +x or on -x."""
    left, right, y_left, y_right, red_first = table
    boxes = (Box(left - 0.05, y_left - 0.05, left + 0.05, y_left + 0.05),
             Box(right - 0.05, y_right - 0.05, right + 0.05, y_right + 0.05))
    return OptionsLayout(boxes[::-1] if red_first else boxes)


@settings(max_examples=200, deadline=None)
@given(two_box_tables)
def test_two_boxes_kernel_and_geometric_gaze_give_the_same_cue(
    table: tuple[float, float, float, float, bool],
) -> None:
    """At N = 2 the paper's printed gaze and the general geometric gaze cue the same box, on
    the same side, with the same strength (1e-12); the kernel is the printed row itself."""
    layout = _two_boxes(table)
    plus_x = 0 if layout.boxes[0].center[0] > EYES[0] else 1
    for level in GAZE_LEVEL_NAMES:
        for j in (0, 1):
            kernel, general = gaze_toward(layout, j, level), geometric_gaze(layout, j, level)
            assert kernel == GAZE_LEVELS[level].toward("red" if j == plus_x else "blue")
            got, want = read_gaze(layout, kernel), read_geometric_gaze(layout, general)
            if level == "neutral":
                assert got == want == (None, 0.0)
                continue
            assert got[0] == want[0] == j
            assert got[1] == cue_strength(level)
            assert abs(got[1] - want[1]) < 1e-12
            assert math.copysign(1, kernel.yaw) == math.copysign(1, general.yaw)


def test_the_paper_table_reads_as_the_paper_person_reads_the_yaw() -> None:
    layout = OptionsLayout.from_table(TableLayout())  # option 0 is red, on +x
    assert read_gaze(layout, GazeCommand(0.53, -0.53)) == (0, 0.53)
    assert read_gaze(layout, GazeCommand(-0.47, 0.31)) == (1, 0.47)
    assert read_gaze(layout, GazeCommand(1e-10, 0.4)) == (None, 0.0)
    assert gaze_toward(layout, None, "extreme") == GazeCommand()
    with pytest.raises(IndexError, match="not on this table"):
        gaze_toward(layout, 2, "low")


def test_three_boxes_and_boxes_on_one_side_take_the_geometric_gaze() -> None:
    row = OptionsLayout.row(3)
    one_side = OptionsLayout((Box(0.6, 0.1, 0.7, 0.2), Box(0.8, 0.1, 0.9, 0.2)))
    for layout in (row, one_side):
        for j in range(layout.n_options):
            assert gaze_toward(layout, j, "moderate") == geometric_gaze(layout, j, "moderate")
            assert read_gaze(layout, gaze_toward(layout, j, "moderate")) == read_geometric_gaze(
                layout, geometric_gaze(layout, j, "moderate"))


# --- the gaze toward any box of a row

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
