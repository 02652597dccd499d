"""Eq 6 over N_o options: the consensus claim for three options, and the freeze."""

from __future__ import annotations

import numpy as np
import pytest

from services.model.bias import BiasParams
from services.model.dynamics import OptionsParams, leading_option, option_vector
from services.model.options_bias import advance_robot, bias_rate, disagrees

THREE = OptionsParams(n_options=3)  # the paper's d, u, α, γ, a_rh = a_hr = 1; β = δ = 0
MS = [0.001] * 4000  # 4 s at the decision model's 1 ms step
# ẑ_h magnitudes a cos θ tanh(k/d): a barely read hand, a hesitant one, a straight-on reach
HUMAN = [0.2, 1.0, 8.0]


@pytest.mark.parametrize("o", [0, 1, 2])
@pytest.mark.parametrize("h", [0, 1, 2])
@pytest.mark.parametrize("m", HUMAN)
def test_the_bias_beats_the_humans_social_influence(o: int, h: int, m: float) -> None:
    """The consensus claim for N_o = 3: from z_r = 0, with the human's opinion held on any
    option (O itself, against which γ < 0 pushes the robot, or another), the robot ends at O."""
    z_hat = m * option_vector(h, 3)
    z_r, s = advance_robot(np.zeros(3), 0.0, z_hat, MS, THREE, o)
    assert leading_option(z_r) == o, (z_r, s)
    assert s > THREE.pair.robot.u  # past the human's largest social influence u_r


@pytest.mark.parametrize("m", HUMAN)
def test_without_the_bias_the_robot_turns_away_from_the_human(m: float) -> None:
    """The same runs with the controller off: the robot never ends on the human's option, so it
    is the bias, not the dynamics alone, that brings it to O = h above."""
    for h in range(3):
        z_r, s = advance_robot(np.zeros(3), 0.0, m * option_vector(h, 3), MS, THREE, None)
        assert s == 0.0
        assert z_r[h] == min(z_r) < 0
        # and it is undecided between the other two: γ pushes it off h, nothing picks one
        assert leading_option(z_r) is None


def test_agreement_freezes_the_bias_and_the_robot_stays_at_o() -> None:
    o = 2
    z_hat = 8.0 * option_vector(o, 3)
    z_r, s = advance_robot(np.zeros(3), 0.0, z_hat, MS, THREE, o)
    assert leading_option(z_r) == o and not disagrees(z_r, z_hat)
    later_z, later_s = advance_robot(z_r, s, z_hat, MS, THREE, o)
    assert later_s == s  # frozen while the pair agrees
    assert leading_option(later_z) == o  # and the frozen bias holds the robot there


def test_the_paper_threshold_alone_does_not_cross_against_the_human() -> None:
    """With b* = u_r (margin 0, the paper's rule) the robot stalls short of O when the human is
    held on O, as in the two-option model (services.model.bias): the margin is needed for any
    N_o."""
    paper = BiasParams(b_star_margin=0.0)
    z_hat = 8.0 * option_vector(0, 3)
    z_r, s = advance_robot(np.zeros(3), 0.0, z_hat, MS * 3, THREE, 0, paper)
    assert leading_option(z_r) != 0
    assert s == pytest.approx(THREE.pair.robot.u, abs=0.05)


def test_the_controller_runs_only_in_disagreement() -> None:
    z_hat = 3.0 * option_vector(1, 3)
    assert not disagrees(np.zeros(3), z_hat)  # an undecided robot: z_r[h] is its largest
    assert not disagrees(np.array([-1.0, 2.0, -1.0]), z_hat)  # both lead with option 1
    assert disagrees(np.array([1.0, -2.0, 1.0]), z_hat)  # the robot against h, tied elsewhere
    assert not disagrees(np.array([1.0, -2.0, 1.0]), np.zeros(3))  # no human reading yet
    # ṡ's σ term grows with how far the robot is against h; its K term stops at b*
    assert bias_rate(0.0, np.array([1.0, -2.0, 1.0]), 1, 0.1, 16.0, 4.0) == pytest.approx(
        0.2 + 1.6 * 4.0
    )
    assert bias_rate(5.0, np.array([1.0, -2.0, 1.0]), 1, 0.1, 16.0, 4.0) == pytest.approx(0.2)
