"""Trial outcome: debounced switches, C/CH/D/DH, violations (SPEC §6)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.debounce import DebounceParams
from services.model.dynamics import option_vector
from services.model.geometry import CommitLine
from services.model.outcome import (
    OptionsOutcomeTracker,
    OutcomeTracker,
    classify,
    count_switches,
    trial_outcome,
)

D = DebounceParams
BEFORE = (0.5, 0.8)  # participant's side of the default commit line (y = 0.45)
AFTER = (0.5, 0.3)  # past the line, on the buzzers' side


def ref_switch_onsets(z: list[float], c_max: int) -> list[int]:
    """Reference: run-length encode the non-zero signs (with their first index); a run against
    the current state, of length >= c_max, is a switch starting at the run's first sample."""
    runs: list[list[int]] = []  # [sign, length, first index]
    for i, v in enumerate(z):
        s = (v > 0) - (v < 0)
        if s == 0:
            continue
        if runs and runs[-1][0] == s:
            runs[-1][1] += 1
        else:
            runs.append([s, 1, i])
    if not runs:
        return []
    state, onsets = runs[0][0], []
    for s, n, first in runs[1:]:
        if s != state and n >= c_max:
            state = s
            onsets.append(first)
    return onsets


@pytest.mark.parametrize(
    ("switches", "human", "robot", "expected"),
    [
        (0, "red", "red", "C"),
        (0, "blue", "blue", "C"),
        (0, "red", "blue", "D"),
        (0, None, "blue", "D"),
        (1, "blue", "blue", "CH"),
        (3, "red", "red", "CH"),
        (1, "blue", "red", "DH"),
        (2, None, "red", "DH"),
    ],
)
def test_classification_table(switches: int, human: str | None, robot: str, expected: str) -> None:
    assert classify(switches, human, robot) == expected  # type: ignore[arg-type]


def test_classify_rejects_negative() -> None:
    with pytest.raises(ValueError):
        classify(-1, "red", "red")


def test_straight_path_is_c_or_d() -> None:
    z = [0.0, 0.0, 0.5, 1.0, 2.0, 3.0]
    out = trial_outcome(z, [BEFORE] * 3 + [AFTER] * 3, "red", "red")
    assert (out.outcome, out.switches, out.violations, out.first_sign) == ("C", 0, 0, 1)
    assert out.crossed_at_index == 3 and out.same_buzzer and out.samples == 6
    assert trial_outcome(z, [None] * 6, "red", "blue").outcome == "D"


def test_one_early_switch_is_allowed() -> None:
    z = [1, 1, -1, -1, -1, -1, -1]
    centers = [BEFORE] * 6 + [AFTER]
    out = trial_outcome(z, centers, "blue", "blue", D(4))
    assert (out.outcome, out.switches, out.violations) == ("CH", 1, 0)
    assert out.switch_indices == (2,) and out.first_sign == 1


def test_default_switch_debounce_is_c_max_four() -> None:
    # SPEC §6: switches are debounced like Algorithm 2 (C_max = 4): a run of three is noise,
    # four is a switch; C vs CH of every stored trial hangs on this.
    assert count_switches([1, -1, -1, -1, 1]) == 0
    assert count_switches([1, -1, -1, -1, -1]) == 1
    assert trial_outcome([1, -1, -1, -1], [None] * 4, "red", "red").outcome == "C"
    assert trial_outcome([1, -1, -1, -1, -1], [None] * 5, "blue", "blue").outcome == "CH"


def test_short_flip_is_not_a_switch_and_zeros_do_not_break_runs() -> None:
    assert count_switches([1, -1, -1, -1, 1, 1], D(4)) == 0
    assert count_switches([1, -1, 0, -1, 0, 0, -1, -1], D(4)) == 1
    assert count_switches([1, -1, -1, 1, -1, -1, -1], D(4)) == 0
    assert count_switches([0, 0, 0], D(1)) == 0
    assert count_switches([-1, 1, -1, 1], D(1)) == 3


def test_second_switch_is_a_violation() -> None:
    z = [1] * 3 + [-1] * 4 + [1] * 4
    out = trial_outcome(z, [BEFORE] * len(z), "red", "blue")
    assert (out.outcome, out.switches, out.violations) == ("DH", 2, 1)
    assert out.extra_switches == 1 and out.late_switches == 0
    z = z + [-1] * 4 + [1] * 4
    out = trial_outcome(z, [BEFORE] * len(z), "red", "red")
    assert (out.switches, out.violations, out.extra_switches) == (4, 3, 3)


def test_switch_after_the_commit_line_is_a_violation() -> None:
    z = [1] * 5 + [-1] * 4
    centers = [BEFORE] * 4 + [AFTER] * 5  # crossed at index 4, switch onset at 5
    out = trial_outcome(z, centers, "blue", "blue")
    assert (out.switches, out.violations, out.late_switches) == (1, 1, 1)
    assert out.crossed_at_index == 4


def test_switch_begun_before_the_line_is_not_late() -> None:
    # Onset at index 3 (before crossing at 4) though confirmed at index 6, after it.
    z = [1] * 3 + [-1] * 4
    centers = [BEFORE] * 4 + [AFTER] * 3
    out = trial_outcome(z, centers, "blue", "blue")
    assert (out.switches, out.violations, out.late_switches) == (1, 0, 0)


def test_crossing_latches_and_a_late_second_switch_counts_once() -> None:
    z = [1] * 2 + [-1] * 4 + [1] * 4
    centers = [BEFORE] * 3 + [AFTER] + [BEFORE] * 6  # crossed at 3, came back below
    out = trial_outcome(z, centers, "red", "red")
    assert out.crossed_at_index == 3
    assert (out.switches, out.late_switches, out.extra_switches) == (2, 1, 1)
    assert out.violations == 1  # the second switch breaks both rules: one violation


def test_mirrored_commit_line() -> None:
    line = CommitLine(y=0.5, start_side="above")
    centers = [(0.5, 0.2), (0.5, 0.6), (0.5, 0.7)]
    out = trial_outcome([1, 1, -1], centers, "red", "red", D(1), line)
    assert out.crossed_at_index == 1 and out.late_switches == 1


def test_validation() -> None:
    with pytest.raises(ValueError):
        DebounceParams(c_max=0)
    with pytest.raises(ValueError):
        OutcomeTracker().add(float("nan"), None)
    with pytest.raises(ValueError):
        trial_outcome([1.0], [], "red", "red")


def test_tracker_reset() -> None:
    tr = OutcomeTracker(D(1))
    for z in (1, -1, 1):
        tr.add(z, AFTER)
    assert tr.switches == 2
    tr.reset()
    assert (tr.switches, tr.sign, tr.samples, tr.crossed_at_index) == (0, 0, 0, None)


z_values = st.lists(st.sampled_from([-2.0, -0.3, 0.0, 0.0, 0.4, 1.5]), max_size=120)


@settings(max_examples=400)
@given(z=z_values, c_max=st.integers(1, 6))
def test_switch_count_equals_reference(z: list[float], c_max: int) -> None:
    onsets = ref_switch_onsets(z, c_max)
    assert count_switches(z, D(c_max)) == len(onsets)
    out = trial_outcome(z, [None] * len(z), "red", "red", D(c_max))
    assert list(out.switch_indices) == onsets
    assert out.violations == max(0, len(onsets) - 1)  # no crossing: only extra switches


@settings(max_examples=300)
@given(z=z_values, c_max=st.integers(1, 6), cross=st.integers(0, 130))
def test_violations_against_reference(z: list[float], c_max: int, cross: int) -> None:
    centers = [BEFORE if i < cross else AFTER for i in range(len(z))]
    out = trial_outcome(z, centers, "blue", "red", D(c_max))
    onsets = ref_switch_onsets(z, c_max)
    crossed = cross if cross < len(z) else None
    assert out.crossed_at_index == crossed
    expected = sum(
        1 for k, o in enumerate(onsets) if k >= 1 or (crossed is not None and o >= crossed)
    )
    assert out.violations == expected
    assert out.violations <= out.switches
    assert out.outcome == ("D" if not onsets else "DH")


# --- switches and violations over N boxes

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
