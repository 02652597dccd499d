"""The LSL outlet's pure parts: the rig clock on LSL's, the signal rows, the markers."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.core import messages as m
from services.lsl.clockmap import Anchor, read_anchor
from services.lsl.samples import (
    PENDING,
    SIGNALS,
    SafeStops,
    SignalRows,
    estop_marker,
    result_marker,
    signal_names,
    trial_marker,
)

rig_ns = st.integers(0, 2**62)
speeds = st.sampled_from([1.0, 0.5, 4.0, 10.0])


@given(rig_ns, st.floats(0, 1e6), speeds, st.integers(-10**12, 10**12))
def test_the_mapping_keeps_intervals_in_wall_seconds_and_inverts(ref, lsl_ref, speed, dt):
    anchor = Anchor(ref, lsl_ref, speed)
    assert anchor.to_lsl(ref) == lsl_ref
    t = max(0, ref + dt)
    assert math.isclose(anchor.to_lsl(t) - lsl_ref, (t - ref) / 1e9 / speed, abs_tol=1e-6)
    # back to the rig clock within LSL's float resolution at this magnitude (µs here)
    assert abs(anchor.to_rig_ns(anchor.to_lsl(t)) - t) <= 2_000 * speed + 1


def test_the_tightest_bracket_is_kept():
    # LSL readings around each rig reading: widths 0.4, 0.02 (the best), 0.1 s
    lsl = iter([10.0, 10.4, 20.0, 20.02, 30.0, 30.1])
    rig = iter([5_000_000_000, 15_000_000_000, 25_000_000_000])
    anchor = read_anchor(lambda: next(rig), lambda: next(lsl), probes=3)
    assert anchor.rig_ns == 15_000_000_000
    assert anchor.lsl_s == pytest.approx(20.01) and anchor.uncertainty_s == pytest.approx(0.01)
    assert anchor.offset_s() == pytest.approx(5.01)


def scalar(seq: int, value: float, t_ns: int = 7) -> m.Opinions:
    """A two-option opinion message of the paper's signed value."""
    return m.Opinions(seq=seq, t_ns=t_ns, src_seq=seq, **m.signed_fields(value))


def pose(seq: int, centre: tuple[float, float] | None) -> m.HandPose:
    if centre is None:
        return m.HandPose(seq=seq, t_ns=1)
    return m.HandPose(seq=seq, t_ns=1, detected=True, center=centre, landmarks=(centre,))


@given(st.permutations(["z_h", "z_r", "b_r"]), st.booleans(), st.booleans())
def test_a_row_comes_once_all_three_values_of_its_pose_are_in_in_any_order(order, seen, found):
    rows = SignalRows()
    if seen:
        rows.on_pose(pose(3, (0.1, 0.9) if found else None))
    values = {"z_h": 0.5, "z_r": -0.2, "b_r": 1.25}
    out = [rows.on_value(name, scalar(3, values[name], t_ns=99)) for name in order]
    assert out[:2] == [None, None]
    row = out[2]
    assert row is not None and row.t_ns == 99
    assert row.values[:3] == (0.5, -0.2, 1.25)
    if seen and found:
        assert row.values[3:] == (0.1, 0.9)
    else:
        assert all(math.isnan(v) for v in row.values[3:])
    assert rows.on_value("z_r", scalar(3, 0.0)) is None  # a repeat starts a new one


def test_only_the_newest_poses_are_waited_for():
    rows = SignalRows()
    for seq in range(PENDING + 10):
        rows.on_value("z_h", scalar(seq, 0.0))
        rows.on_value("z_r", scalar(seq, 0.0))
    assert rows.on_value("b_r", scalar(0, 0.0)) is None  # long given up
    assert rows.on_value("b_r", scalar(PENDING + 9, 0.0)) is not None
    with pytest.raises(ValueError):
        rows.on_value("theta", scalar(1, 0.0))


def test_three_options_make_one_channel_per_option_and_another_set_is_refused():
    names = ("red", "blue", "green")
    assert signal_names() == SIGNALS == ("z_h", "z_r", "b_r", "hand_x", "hand_y")
    assert signal_names(names) == (
        "z_h:red", "z_h:blue", "z_h:green", "z_r:red", "z_r:blue", "z_r:green",
        "b_r:red", "b_r:blue", "b_r:green", "hand_x", "hand_y")
    rows = SignalRows(names)
    assert rows.names == signal_names(names)
    rows.on_pose(pose(5, (0.2, 0.8)))
    vectors = {"z_h": (0.5, -0.25, -0.25), "z_r": (0.0, 0.1, -0.1), "b_r": (1.0, -2.0, 1.0)}
    out = [rows.on_value(q, m.Opinions(seq=5, t_ns=9, src_seq=5, options=names, values=v))
           for q, v in vectors.items()]
    row = out[-1]
    assert row is not None and len(row.values) == len(rows.names)
    assert row.values == (*vectors["z_h"], *vectors["z_r"], *vectors["b_r"], 0.2, 0.8)
    with pytest.raises(m.MessageError, match="this rig runs red,blue,green"):
        rows.on_value("z_h", scalar(6, 0.5))  # the paper's two options: another set


def test_markers_are_json_with_what_an_analyst_needs():
    common = {"seq": 0, "t_ns": 0, "trial": 4, "mode": "consensus", "option": "red",
              "session": "S1", "options": ("red", "blue")}
    assert json.loads(trial_marker(m.TrialEvent(phase="setup", text="low", **common))) == {
        "event": "setup", "trial": 4, "session": "S1", "mode": "consensus", "option": "red",
        "gaze": "low"}
    assert json.loads(trial_marker(m.TrialEvent(phase="countdown", text="2", **common))) == {
        "event": "countdown", "trial": 4, "session": "S1", "word": "2"}
    assert json.loads(trial_marker(m.TrialEvent(phase="interrupted", text="e-stop", **common))) \
        == {"event": "interrupted", "trial": 4, "session": "S1", "why": "e-stop"}
    res = m.TrialResult(seq=0, t_ns=0, options=("red", "blue"), trial=4, mode="consensus",
                        option="red", robot="red", human=None, outcome=None, score=0,
                        session="S1")
    assert json.loads(result_marker(res)) == {"event": "result", "trial": 4, "session": "S1",
                                              "robot": "red", "score": 0}
    assert json.loads(estop_marker(m.Estop(seq=0, t_ns=0, engaged=False, source="op@ctl"))) == {
        "event": "estop_release", "source": "op@ctl"}


def test_any_other_option_set_gets_the_same_markers_naming_its_options():
    names = ("red", "blue", "green")
    ev = m.TrialEvent(seq=0, t_ns=0, options=names, phase="setup", trial=4, mode="consensus",
                      option="green", text="low", session="S1")
    assert json.loads(trial_marker(ev)) == {
        "event": "setup", "trial": 4, "session": "S1", "options": list(names),
        "mode": "consensus", "option": "green", "gaze": "low"}
    res = m.TrialResult(seq=0, t_ns=0, options=names, trial=4, mode="consensus",
                        option="green", robot="green", human="blue", outcome="D", score=0,
                        session="S1")
    assert json.loads(result_marker(res)) == {
        "event": "result", "trial": 4, "session": "S1", "outcome": "D", "robot": "green",
        "human": "blue", "score": 0, "options": list(names)}


def test_a_safe_stop_is_marked_where_it_begins_and_ends_per_device():
    stops = SafeStops()
    seen = [stops.on_state(d, s, r) for d, s, r in (
        ("actuation", False, ""), ("actuation", True, "stale"), ("actuation", True, "stale"),
        ("eyes", True, "estop"), ("actuation", False, ""), ("eyes", False, ""))]
    assert [json.loads(x) if x else None for x in seen] == [
        None, {"event": "safe_stop", "device": "actuation", "reason": "stale"}, None,
        {"event": "safe_stop", "device": "eyes", "reason": "estop"},
        {"event": "safe_stop_cleared", "device": "actuation"},
        {"event": "safe_stop_cleared", "device": "eyes"}]
