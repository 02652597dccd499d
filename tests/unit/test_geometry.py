"""The buzzer the arm presses: the box centre nearest its end effector (SPEC §4), worked by hand.

The default boxes (SPEC §2): red x 0.72-0.86, blue x 0.14-0.28, both y 0.12-0.26, so the
centres are (0.79, 0.19) and (0.21, 0.19) and the first corners (0.72, 0.12) and (0.14, 0.12).
Measured to the centres the boundary is x = 0.5; measured to the corners (Algorithm 2's anchor)
it is x = 0.43. Between the two lines the answers differ: the centre says blue.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.behaviour import RobotBehaviour
from services.model.geometry import Box, TableLayout

LAYOUT = TableLayout()
# Boxes with dyadic corners, so that a point on the midline x = 0.5 is exactly as far from one
# centre, (0.75, 0.25), as from the other, (0.25, 0.25): a true tie, not one rounding decides.
EXACT = TableLayout(red=Box(0.625, 0.125, 0.875, 0.375), blue=Box(0.125, 0.125, 0.375, 0.375))
MIRRORED = TableLayout(red=EXACT.blue, blue=EXACT.red)


@pytest.mark.parametrize(
    ("point", "expected", "why"),
    [
        # to the centres 0.34 (red) vs 0.24 (blue); to the corners 0.279 (red) vs 0.318 (blue)
        ((0.45, 0.19), "blue", "nearer blue's centre, nearer red's corner"),
        # to the centres 0.329 (red) vs 0.292 (blue); to the corners 0.243 (red) vs 0.342
        ((0.48, 0.08), "blue", "above the boxes, between the two boundaries"),
        ((0.44, 0.60), "blue", "below the boxes: centres 0.539 vs 0.470, corners 0.556 vs 0.566"),
        ((0.52, 0.19), "red", "just right of the midline"),
        ((0.79, 0.19), "red", "on red's centre"),
        ((0.14, 0.12), "blue", "on blue's corner"),
        ((0.72, 0.26), "red", "on a corner of red that is not its first"),
        ((0.0, 1.0), "blue", "far corner of the image, blue side"),
    ],
)
def test_the_nearest_buzzer_is_measured_to_the_box_centre(point, expected, why):
    assert LAYOUT.nearest(point) == expected, why


@settings(max_examples=100, deadline=None)
@given(x=st.floats(0.431, 0.499), y=st.floats(0.0, 1.0))
def test_the_band_between_corner_and_centre_boundaries_is_blue(x, y):
    # Left of x = 0.5 blue's centre is nearer, whatever the height: (x - 0.21)² < (0.79 - x)².
    assert LAYOUT.nearest((x, y)) == "blue"


@pytest.mark.parametrize("y", [0.0, 0.125, 0.25, 0.5, 0.875, 1.0])
def test_an_exact_tie_goes_to_red(y):
    # Algorithm 2: "if d_blue < d_red press blue, else red"; the docstring keeps that rule.
    assert EXACT.nearest((0.5, y)) == "red"
    assert MIRRORED.nearest((0.5, y)) == "red"  # the rule is about colour, not side
    assert EXACT.nearest((0.5 - 2**-20, y)) == "blue"  # one step off the tie: the geometry
    assert MIRRORED.nearest((0.5 + 2**-20, y)) == "blue"


def test_the_arm_presses_the_centre_nearest_buzzer_when_the_human_presses():
    # Through Algorithm 2's state machine: the human pressed red, the arm is at (0.45, 0.19),
    # nearer blue's centre: the arm presses blue (measured to corners it would press red).
    b = RobotBehaviour(LAYOUT)
    b.start(0.0, 10.0)
    b.step(0.1, -1.0, None, (0.5, 0.08))
    cmd = b.step(0.2, -1.0, "red", (0.45, 0.19))
    assert (cmd.action, cmd.target) == ("press", "blue")


def test_a_timeout_at_an_exact_tie_presses_red():
    b = RobotBehaviour(EXACT)
    b.start(0.0, 1.0)
    cmd = b.step(1.0, None, None, (0.5, 0.25))
    assert (cmd.action, cmd.target) == ("press", "red") and "timeout" in cmd.reason


def test_the_arm_at_home_midway_between_the_default_boxes_presses_red():
    # The default centres round to 0.79 and 0.21000000000000002: home (0.5, 0.08) is 1 ulp
    # nearer blue, a tie all the same.
    assert LAYOUT.nearest((0.5, 0.08)) == "red"
