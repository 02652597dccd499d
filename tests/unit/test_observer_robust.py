"""The default (robust) observer on realistic paths, and its rules one by one; the same reading
over N_o boxes (`OptionsObserver`): the robust observer over two boxes exactly, the standard
over three."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from services.analysis.observer_eval import (
    HAND_RADIUS,
    HEIGHT,
    WIDTH,
    Leg,
    Path,
    evaluate,
    evaluate_options,
    frames,
    paths,
    reaches,
    score,
    score_options,
)
from services.model.debounce import DebounceParams
from services.model.dynamics import leading_option
from services.model.geometry import HAND_TEMPLATE, OptionsLayout, TableLayout
from services.model.observer import ObserverParams
from services.model.observer_robust import OptionsObserver, RobustObserver, make_observer
from services.model.outcome import OutcomeTracker

LAYOUT = TableLayout()
ROBUST = ObserverParams()


@pytest.mark.parametrize("hz", [30.0, 60.0])
def test_default_observer_meets_the_targets_on_realistic_paths(hz):
    # The targets of docs/observer.md, on paths made independently of the simulated participant,
    # with 1-3 px of tracker jitter: wrong side ≤ 1% of frames, ≤ 0.1 spurious switches per
    # reach, ≤ 150 ms of added latency. (benchmarks/observer_paths.py runs more seeds and prints
    # the paper's.)
    s = evaluate(ROBUST, hz, seeds=2)
    assert s.wrong_frac <= 0.01, s
    assert s.spurious_per_reach <= 0.1, s
    assert s.added_median <= 0.15 and s.added_p90 <= 0.15, s


def test_the_paper_mode_is_what_the_paper_prints_and_fails_where_measured():
    # Kept for replication, and as the baseline the robust mode is judged against.
    s = evaluate(ObserverParams(mode="paper"), 30.0, seeds=1)
    assert s.wrong_frac > 0.05 and s.spurious_per_reach > 0.5
    assert make_observer(ObserverParams(mode="paper")).__class__.__name__ == "PaperObserver"


def feed(obs: RobustObserver, points, hz: float = 30.0, t0: float = 0.0):
    out = []
    for i, p in enumerate(points):
        out.append(obs.update([p], t0 + i / hz))
    return out


def line(a, b, n):
    return [
        (a[0] + (b[0] - a[0]) * i / (n - 1), a[1] + (b[1] - a[1]) * i / (n - 1)) for i in range(n)
    ]


@pytest.mark.parametrize("colour", ["red", "blue"])
def test_a_reach_reads_its_box_and_drawing_back_holds_it(colour):
    obs = RobustObserver(ROBUST, LAYOUT)
    box = LAYOUT.box(colour).center
    reach = feed(obs, line((0.5, 0.85), (0.5 + (box[0] - 0.5) * 0.6, 0.5), 30))
    sign = 1 if colour == "red" else -1
    assert sign * reach[-1].z_hat > 0 and reach[-1].target == colour
    back = feed(obs, line((0.5 + (box[0] - 0.5) * 0.6, 0.5), (0.5, 0.85), 30), t0=1.0)
    assert all(sign * o.z_hat > 0 for o in back)  # drawing back never reads the other box...
    assert len({o.z_hat for o in back[8:]}) == 1  # ...and, once the window has turned, holds
    held = back[-1].z_hat
    still = feed(obs, [(0.5, 0.85)] * 30, t0=2.0)
    assert all(o.z_hat == held for o in still) and not any(o.moved for o in still[8:])


def test_sideways_is_neither_box():
    obs = RobustObserver(ROBUST, LAYOUT)
    out = feed(obs, line((0.4, 0.8), (0.6, 0.8), 30))  # along the participant's edge
    assert all(o.z_hat == 0.0 for o in out)


@settings(max_examples=60, deadline=None)
@given(hz=st.sampled_from([15.0, 30.0, 60.0, 120.0]), frac=st.floats(0.3, 0.9))
def test_the_reading_does_not_depend_on_the_frame_rate(hz, frac):
    # The same movement in time gives the same ẑ_h at the same moment, whatever the camera rate.
    box = LAYOUT.red.center
    end = (0.5 + (box[0] - 0.5) * frac, 0.85 + (box[1] - 0.85) * frac)

    def at_one_second(rate: float) -> float:
        obs = RobustObserver(ROBUST, LAYOUT)
        n = int(rate) + 1
        return feed(obs, line((0.5, 0.85), end, n), rate)[-1].z_hat

    assert at_one_second(hz) == pytest.approx(at_one_second(240.0), rel=0.15)


def test_an_unclear_bearing_does_not_flip_the_reading():
    # Straight up between the boxes: neither is clearly the target; once a side is read, a
    # movement that points at the other box only slightly more does not flip it.
    obs = RobustObserver(ROBUST, LAYOUT)
    feed(obs, line((0.5, 0.85), (0.62, 0.6), 20))
    assert obs.z_hat > 0
    out = feed(obs, line((0.62, 0.6), (0.615, 0.3), 30), t0=1.0)  # almost straight up
    assert all(o.z_hat > 0 for o in out)


def test_eq7_magnitude_and_bounds():
    obs = RobustObserver(ROBUST, LAYOUT)
    out = feed(obs, line((0.5, 0.85), LAYOUT.red.center, 40))
    o = next(o for o in reversed(out) if o.moved)
    expected = ROBUST.a * math.cos(o.theta) * math.tanh(ROBUST.k / o.distance)
    assert o.z_hat == pytest.approx(expected)
    assert all(abs(x.z_hat) <= ROBUST.a for x in out)


def test_every_path_is_scored_both_ways():
    assert len(paths()) == 12 and sum(p.switches for p in paths()) == 2
    s = score(paths()[3], ROBUST, 30.0, 2.0, 0)  # the change of mind
    assert len(s.latencies) == 2 and all(math.isfinite(v) for v in s.latencies)


REST = (0.5, 0.85)  # the hand's rest on the participant's edge, midway between the boxes


def hand_at(x: float, y: float) -> list[tuple[float, float]]:
    """The 21 landmarks of a hand whose centre is (x, y)."""
    return [(float(a), float(b)) for a, b in np.array([x, y]) + HAND_TEMPLATE * HAND_RADIUS]


def sign_changes(z_hats: list[float]) -> int:
    """How often the reading changes side (zeros carry no side)."""
    sides = [z > 0 for z in z_hats if z != 0]
    return sum(a != b for a, b in zip(sides, sides[1:], strict=False))


# The history gate. At "go" the observer is reset while the hand rests; the tracker's centre
# wobbles by a pixel or two from frame to frame. With ≥ 0.5·window_s of history a wobble of up
# to 1.5 px per axis moves the smoothed centre at most (1 − e^(−0.06/0.06))·3 px ≈ 1.9 px per
# axis, i.e. 0.0049 in normalised units, under min_speed·0.06 s = 0.006: no reading. With a
# shorter history (the mutant 0.05·window_s) the threshold min_speed·span shrinks with the span
# and one frame's wobble reads a box before the hand has moved.
@settings(max_examples=80, deadline=None)
@example(hz=120.0, wobble=[(-1.5, 1.5), (1.5, -1.5)] + [(0.0, 0.0)] * 58)  # up-right: red
@example(hz=60.0, wobble=[(1.5, 1.5), (-1.5, -1.5)] + [(0.0, 0.0)] * 58)  # up-left: blue
@given(
    hz=st.sampled_from([30.0, 60.0, 120.0, 240.0]),
    wobble=st.lists(
        st.tuples(st.floats(-1.5, 1.5), st.floats(-1.5, 1.5)), min_size=60, max_size=60
    ),
)
def test_a_resting_hand_that_wobbles_reads_no_box(hz, wobble):
    obs = RobustObserver(ROBUST, LAYOUT)
    out = [
        obs.update(hand_at(REST[0] + dx / WIDTH, REST[1] + dy / HEIGHT), i / hz)
        for i, (dx, dy) in enumerate(wobble)
    ]
    assert all(o.z_hat == 0.0 and not o.moved for o in out), [o.z_hat for o in out]


def test_a_wobble_in_the_first_frames_does_not_count_as_a_switch():
    # A rest at "go", then a reach to blue; the first two frames wobble 3 px toward red (a
    # tracker's frame-to-frame error). The outcome must see one direction (blue) and no switch:
    # a reading taken on two frames of history would start red and then "switch" to blue.
    hz = 120.0
    reach = Path("reach to blue", REST, (Leg(None, 0.5), Leg(LAYOUT.blue.center, 1.2, "blue")))
    wobble = {0: (-1.5, 1.5), 1: (1.5, -1.5)}  # px: left-down, then right-up
    obs = RobustObserver(ROBUST, LAYOUT)
    tracker = OutcomeTracker(DebounceParams(), LAYOUT.commit, ROBUST.switch_dead_band)
    for i, (t, (x, y), _) in enumerate(reach.sample(hz)):
        dx, dy = wobble.get(i, (0.0, 0.0))
        o = obs.update(hand_at(x + dx / WIDTH, y + dy / HEIGHT), t)
        tracker.add(o.z_hat, o.center)
    result = tracker.result("blue", "blue")
    assert (result.first_sign, result.switches, result.outcome) == (-1, 0, "C")


# The switch margin. Straight up between the boxes their bearings are symmetric: a heading a
# few degrees either side of the midline points at one box only slightly more directly than at
# the other. Past the margin (0.15 in cos θ) the reading may move; within it, it must not.
@settings(max_examples=60, deadline=None)
@example(hz=60.0, speed=0.5, weave_deg=2.0, period=0.3, phase=0.0)
@given(
    hz=st.sampled_from([30.0, 60.0, 120.0]),
    speed=st.floats(0.3, 0.8),  # units/s up the table
    weave_deg=st.floats(0.5, 3.0),  # the heading's largest angle from straight up
    period=st.floats(0.2, 0.5),  # s per weave
    phase=st.floats(0.0, 2 * math.pi),
)
def test_a_reach_weaving_up_the_midline_keeps_its_first_reading(
    hz, speed, weave_deg, period, phase
):
    # x = 0.5 + A·sin(2πt/T + φ) while y rises at `speed`: the heading stays within ±weave_deg
    # of straight up, so (the boxes' bearings at most 60° from up while a box can be read) the
    # other box's advantage is at most 2·sin 60°·sin(3° + 0.6°) ≈ 0.11 < switch_margin, the
    # 0.6° allowing for the hand being up to A off the midline.
    amp = speed * period * math.tan(math.radians(weave_deg)) / (2 * math.pi)
    obs = RobustObserver(ROBUST, LAYOUT)
    z_hats = []
    for i in range(int((REST[1] - 0.3) / speed * hz) + 1):
        t = i / hz
        x = 0.5 + amp * (math.sin(2 * math.pi * t / period + phase) - math.sin(phase))
        z_hats.append(obs.update(hand_at(x, REST[1] - speed * t), t).z_hat)
    assert any(z != 0 for z in z_hats)  # the reach was read...
    assert sign_changes(z_hats) == 0  # ...and kept its side


def test_an_undecided_reach_up_the_middle_does_not_chatter():
    # A minimum-jerk reach straight up between the boxes (the realistic paths' 1.2 s), with 1-2
    # px of tracker jitter: the outcome counts no switch and the reading keeps its side. Without
    # the margin this path switches about three times per reach.
    undecided = Path("up the middle", REST, (Leg(None, 0.5), Leg((0.5, 0.3), 1.2), Leg(None, 0.3)))
    changes = switches = 0
    for hz in (30.0, 60.0, 120.0):
        for jitter in (1.0, 2.0):
            for seed in range(5):
                obs = RobustObserver(ROBUST, LAYOUT)
                tracker = OutcomeTracker(DebounceParams(), LAYOUT.commit, ROBUST.switch_dead_band)
                z_hats = []
                for t, landmarks, _ in frames(undecided, hz, jitter, np.random.default_rng(seed)):
                    z = obs.update(landmarks, t).z_hat
                    tracker.add(z, None)
                    z_hats.append(z)
                assert any(z != 0 for z in z_hats)
                changes += sign_changes(z_hats)
                switches += tracker.switches
    assert (changes, switches) == (0, 0)


# -- N_o boxes ----------------------------------------------------------------------------------


@pytest.mark.parametrize("hz", [30.0, 60.0])
def test_two_boxes_read_exactly_as_the_robust_observer(hz: float) -> None:
    table = TableLayout()
    params = ObserverParams()
    rng = np.random.default_rng(3)
    read = 0
    for path in paths(table):
        robust = RobustObserver(params, table)
        plain = OptionsObserver(OptionsLayout.from_table(table), params, neighbour_share=None)
        # the default caps the switch margin by the bearings' gap, which two boxes this far
        # apart never reach on these paths: it reads them exactly as well
        capped = OptionsObserver(OptionsLayout.from_table(table), params)
        for t, landmarks, _ in frames(path, hz, 2.0, rng):
            z = robust.update(landmarks, t).z_hat
            assert plain.update(landmarks, t).z_hat.tolist() == [z, -z]  # exactly
            assert capped.update(landmarks, t).z_hat.tolist() == [z, -z]
            read += z != 0.0
    assert read > 500  # the paths were read, not held at zero throughout


def test_no_hand_holds_the_reading() -> None:
    layout = OptionsLayout.row(3)
    obs = OptionsObserver(layout)
    reach = reaches(layout)[0]  # straight reach to box 0
    for t, centre, _ in reach.sample(30.0):
        obs.update([centre], t)
    held = obs.z_hat
    assert leading_option(held) == 0
    out = obs.update(None, 5.0)
    assert not out.detected and out.z_hat.tolist() == held.tolist()
    assert abs(float(held.sum())) < 1e-12


def test_row_layout_spaces_boxes_on_the_paper_edge() -> None:
    two = OptionsLayout.row(2)
    assert [b.center[0] for b in two.boxes] == pytest.approx([0.21, 0.79])
    assert two.boxes[0].x2 - two.boxes[0].x1 == pytest.approx(0.14)
    seven = OptionsLayout.row(7)
    gaps = [b.x1 - a.x2 for a, b in zip(seven.boxes, seven.boxes[1:], strict=False)]
    assert min(gaps) > 0  # narrowed so that neighbours never touch
    with pytest.raises(ValueError, match="at least 2 boxes"):
        OptionsLayout.row(1)


def test_every_clean_reach_ends_on_its_box() -> None:
    layout = OptionsLayout.row(3)
    for reach in reaches(layout):
        s = score_options(reach, layout, ObserverParams(), 30.0, 0.0, 0)
        assert s.latencies[-1] < 1.0, reach.name  # the final box is read, and for good


@pytest.mark.parametrize("hz", [30.0, 60.0])
def test_three_boxes_meet_the_standard_on_jittered_paths(hz: float) -> None:
    """The benchmark's standard on one seed: wrong-argmax frames ≤ 2 %, few extra changes."""
    s = evaluate_options(3, ObserverParams(), hz, seeds=1)
    assert s.wrong_frac <= 0.02, s
    assert s.extra_per_reach <= 0.2, s


def test_without_the_cap_neighbouring_boxes_hold_the_old_reading() -> None:
    """Why the margin is capped: a fixed 0.15 misreads four boxes in a row far more often."""
    layout = OptionsLayout.row(4)
    turns = [r for r in reaches(layout) if "turns" in r.name]

    def wrong(share: float | None) -> float:
        scores = []
        for r in turns:
            obs = OptionsObserver(layout, ObserverParams(), neighbour_share=share)
            scores.append(score_options(r, layout, ObserverParams(), 30.0, 2.0, 0, observer=obs))
        return sum(s.wrong for s in scores) / sum(s.counted for s in scores)

    assert wrong(None) > 2 * wrong(0.5)
