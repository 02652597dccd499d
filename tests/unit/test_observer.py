"""Observed human opinion, the paper mode: eq 7 and Algorithm 1 as printed (SPEC §2)."""

from __future__ import annotations

import math

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from services.model.geometry import Box, TableLayout
from services.model.observer import (
    ObserverParams,
    PaperObserver,
    anchor_point,
    fold_theta,
    hand_center,
    observe_movement,
)

LAYOUT = TableLayout()
PARAMS = ObserverParams(mode="paper")  # Algorithm 1 as printed: what these tests pin down


def mirrored(layout: TableLayout) -> TableLayout:
    """The same table seen with x → 1 − x (red and blue swap sides)."""

    def flip(b: Box) -> Box:
        return Box(1.0 - b.x2, b.y1, 1.0 - b.x1, b.y2)

    return TableLayout(red=flip(layout.red), blue=flip(layout.blue), commit=layout.commit)


def hand(p, spread=0.01, n=21):
    """n landmarks whose mean is p."""
    offsets = [(spread * math.cos(i), spread * math.sin(i)) for i in range(n)]
    mx = sum(o[0] for o in offsets) / n
    my = sum(o[1] for o in offsets) / n
    return [(p[0] + ox - mx, p[1] + oy - my) for ox, oy in offsets]


# Start points on the participant's side, horizontally between the two anchors: from there a
# hand heading for an anchor moves up and toward that side (see the observer's module doc).
def start_points(anchor):
    lo = LAYOUT.blue.corner[0] if anchor == "corner" else LAYOUT.blue.center[0]
    hi = LAYOUT.red.corner[0] if anchor == "corner" else LAYOUT.red.center[0]
    return st.tuples(st.floats(lo + 0.01, hi - 0.01), st.floats(0.35, 0.95))


@pytest.mark.parametrize("anchor", ["corner", "center"])
@pytest.mark.parametrize("colour", ["red", "blue"])
@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_heading_for_a_box_reads_its_sign(anchor, colour, data):
    params = ObserverParams(anchor=anchor)
    start = data.draw(start_points(anchor))
    speed = data.draw(st.floats(0.003, 0.03))  # per frame, above the noise threshold
    target = anchor_point(LAYOUT, colour, anchor)
    obs = PaperObserver(params, LAYOUT)
    obs.update(hand(start))
    p = start
    for _ in range(5):
        dx, dy = target[0] - p[0], target[1] - p[1]
        dist = math.hypot(dx, dy)
        step = min(speed, dist - 0.01)
        assume(step >= params.noise_threshold)
        p = (p[0] + dx / dist * step, p[1] + dy / dist * step)
        o = obs.update(hand(p))
        assert o.moved and o.target == colour
        assert (o.z_hat > 0) if colour == "red" else (o.z_hat < 0)


@settings(max_examples=200, deadline=None)
@given(
    prev=st.tuples(st.floats(0, 1), st.floats(0, 1)),
    cur=st.tuples(st.floats(0, 1), st.floats(0, 1)),
)
def test_mirroring_flips_nothing(prev, cur):
    params = ObserverParams(anchor="center")
    a = observe_movement(prev, cur, LAYOUT, params)
    flip = mirrored(LAYOUT)
    assert not flip.red_on_right
    b = observe_movement((1 - prev[0], prev[1]), (1 - cur[0], cur[1]), flip, params)
    if a is None:
        assert b is None
        return
    assert b is not None
    assert b[1] == a[1]  # same target colour
    assert b[0] == pytest.approx(a[0], abs=1e-9)
    assert b[2] == pytest.approx(a[2], abs=1e-9)
    assert b[3] == pytest.approx(a[3], abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(
    prev=st.tuples(st.floats(0, 1), st.floats(0, 1)),
    cur=st.tuples(st.floats(0, 1), st.floats(0, 1)),
)
def test_mirroring_keeps_sign_with_corner_anchor(prev, cur):
    # The corner anchor is not mirror-symmetric (the first corner is the box's left edge on
    # either side), so only θ, the target and the sign must agree.
    a = observe_movement(prev, cur, LAYOUT, PARAMS)
    b = observe_movement((1 - prev[0], prev[1]), (1 - cur[0], cur[1]), mirrored(LAYOUT), PARAMS)
    assert (a is None) == (b is None)
    if a is not None and b is not None:
        assume(abs(a[0] - math.pi / 2) > 1e-9)  # cos θ ≈ 0: the sign is rounding noise
        assert b[1] == a[1]
        assert b[0] == pytest.approx(a[0], abs=1e-9)
        assert math.copysign(1, b[3]) == math.copysign(1, a[3])


@settings(max_examples=300, deadline=None)
@given(
    prev=st.tuples(st.floats(-0.5, 1.5), st.floats(-0.5, 1.5)),
    cur=st.tuples(st.floats(-0.5, 1.5), st.floats(-0.5, 1.5)),
    anchor=st.sampled_from(["corner", "center"]),
)
def test_z_hat_bounded_and_theta_folded(prev, cur, anchor):
    params = ObserverParams(anchor=anchor)
    r = observe_movement(prev, cur, LAYOUT, params)
    if math.dist(prev, cur) < params.noise_threshold:
        assert r is None
        return
    assert r is not None
    theta, target, distance, z_hat = r
    assert 0.0 <= theta < math.pi
    assert target == ("red" if theta < math.pi / 2 else "blue")
    assert distance >= params.d_min
    assert abs(z_hat) <= params.a
    assert z_hat == pytest.approx(params.a * math.cos(theta) * math.tanh(params.k / distance))


def test_fold_theta_quadrants():
    # Up-right → first quadrant (red); up-left → second (blue); down-left → shifted to the
    # first; down-right → second (Algorithm 1's point reflection).
    assert fold_theta(1.0, -1.0) == pytest.approx(math.pi / 4)
    assert fold_theta(-1.0, -1.0) == pytest.approx(3 * math.pi / 4)
    assert fold_theta(-1.0, 1.0) == pytest.approx(math.pi / 4)
    assert fold_theta(1.0, 1.0) == pytest.approx(3 * math.pi / 4)
    assert fold_theta(1.0, 0.0) == 0.0
    assert fold_theta(-1.0, 0.0) == 0.0
    assert fold_theta(1.0, 1e-300) < math.pi  # a wrap to exactly 2π must not escape [0, π)


def test_first_frame_gives_zero():
    o = PaperObserver(PARAMS, LAYOUT).update(hand((0.5, 0.8)))
    assert o.z_hat == 0.0 and o.detected and not o.moved
    assert o.center == pytest.approx((0.5, 0.8))
    assert o.movement is None and o.theta is None


def test_still_hand_keeps_previous_value():
    obs = PaperObserver(PARAMS, LAYOUT)
    obs.update(hand((0.5, 0.8)))
    moved = obs.update(hand((0.52, 0.78)))
    assert moved.moved and moved.z_hat > 0
    still = obs.update(hand((0.5205, 0.7795)))  # jitter below the threshold
    assert not still.moved and still.detected
    assert still.z_hat == moved.z_hat
    assert still.theta is None and still.target is None
    assert still.movement == pytest.approx((0.0005, -0.0005))


def test_no_hand_keeps_value_and_flags_stale():
    obs = PaperObserver(PARAMS, LAYOUT)
    obs.update(hand((0.5, 0.8)))
    z = obs.update(hand((0.52, 0.78))).z_hat
    for lost in (None, []):
        o = obs.update(lost)
        assert o.z_hat == z and not o.detected and not o.moved and o.center is None
    # The next detection measures M from the last centre seen: up-left now reads blue.
    back = obs.update(hand((0.50, 0.76)))
    assert back.movement == pytest.approx((-0.02, -0.02))
    assert back.z_hat < 0 and back.target == "blue"


def test_reference_accepted_accumulates_slow_motion():
    slow = [(0.5 + 0.001 * i, 0.8 - 0.001 * i) for i in range(6)]  # 0.0014 per frame
    per_frame = PaperObserver(ObserverParams(reference="frame"), LAYOUT)
    accumulated = PaperObserver(ObserverParams(reference="accepted"), LAYOUT)
    for p in slow:
        a = per_frame.update([p])
        b = accumulated.update([p])
    assert a.z_hat == 0.0  # every frame under the threshold
    assert b.z_hat > 0  # 0.0028 after two frames: read as heading red


def test_reset_forgets_history():
    obs = PaperObserver(PARAMS, LAYOUT)
    obs.update([(0.5, 0.8)])
    obs.update([(0.55, 0.75)])
    obs.reset()
    assert obs.z_hat == 0.0 and obs.last is None
    assert obs.update([(0.3, 0.3)]).z_hat == 0.0


def test_hand_center_any_count():
    assert hand_center([(0.2, 0.4)]) == (0.2, 0.4)
    assert hand_center([(0.0, 0.0), (1.0, 0.5)]) == (0.5, 0.25)


def test_distance_clamped_at_anchor():
    anchor = LAYOUT.red.corner
    r = observe_movement((anchor[0] - 0.01, anchor[1] + 0.01), anchor, LAYOUT, PARAMS)
    assert r is not None
    assert r[2] == PARAMS.d_min
    assert r[3] == pytest.approx(PARAMS.a * math.cos(math.pi / 4))


@pytest.mark.parametrize(
    "kwargs",
    [
        {"a": 0.0},
        {"k": -1.0},
        {"noise_threshold": -0.1},
        {"d_min": 0.0},
        {"a": float("inf")},
        {"anchor": "middle"},
        {"reference": "sometimes"},
    ],
)
def test_params_validation(kwargs):
    with pytest.raises(ValueError):
        ObserverParams(**kwargs)
