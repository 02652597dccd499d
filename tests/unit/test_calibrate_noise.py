"""The 51-person noise of `nod calibrate-cohort`: a parametric bootstrap of the model at the
paper's size. Its p must be calibrated (a "paper" that is itself a study of the model is rarely
called far), small for a paper far from the model, and the same for the same seed (seconds)."""

from __future__ import annotations

import numpy as np
import pytest

from services.cohort.outcomes import Outcomes, flows, shares
from services.sim.calibrate import check, study_noise
from services.sim.calibrate import main as calibrate_main

LABELS: tuple[str | None, ...] = ("C", "CH", "D", "DH", None)


def model_cohort(n: int, seed: int) -> list[Outcomes]:
    """A synthetic model: people whose trials 1-3 lean D and 4-8 lean C, a few timeouts."""
    rng = np.random.default_rng(seed)
    early, late = [0.3, 0.02, 0.65, 0.02, 0.01], [0.6, 0.25, 0.1, 0.04, 0.01]
    return [[LABELS[int(rng.choice(5, p=early if k < 3 else late))] for k in range(8)]
            for _ in range(n)]


def test_a_paper_drawn_from_the_model_is_rarely_called_far() -> None:
    # 200 "papers", each 51 people of the model: p < 0.05 should come up ≈ 5 % of the time
    # (a little less: TVDs of 51 people tie, and a tie counts as "as far").
    model = model_cohort(300, seed=7)
    rng = np.random.default_rng(11)
    ps: list[float] = []
    for _ in range(200):
        paper = [model[i] for i in rng.integers(0, len(model), 51)]
        c = check(model, 0, shares(paper), flows(paper))
        noise = study_noise(model, c, size=51, studies=200, seed=int(rng.integers(10**6)))
        ps += [*noise.trial_p.values(), noise.flow_p]
    low = np.mean(np.array(ps) < 0.05)
    assert 0.01 <= low <= 0.10, low
    assert 0.35 <= np.mean(np.array(ps) < 0.5) <= 0.65  # uniform-ish in the middle too


def test_a_paper_far_from_the_model_has_p_near_0_above_its_floor() -> None:
    model = model_cohort(300, seed=7)
    paper = [["D" if k < 3 else "CH" for k in range(8)] for _ in range(51)]  # all D, then all CH
    c = check(model, 0, shares(paper), flows(paper))
    noise = study_noise(model, c, size=51, studies=500, seed=3)
    assert all(p == 0.0 for p in noise.trial_p.values()) and noise.flow_p == 0.0
    assert all(c.trial_tvd[k] > noise.trial_floor[k] for k in noise.trial_floor)
    assert all(0 < f < 0.3 for f in noise.trial_floor.values())  # 51 people: ≈ 0.1-0.2
    assert 0 < noise.flow_floor < c.flow_tvd


def test_the_noise_is_reproducible_with_its_seed_and_shrinks_with_the_study() -> None:
    model = model_cohort(200, seed=5)
    c = check(model, 0, shares(model[:51]), flows(model[:51]))
    a, b = (study_noise(model, c, size=51, studies=300, seed=9) for _ in range(2))
    assert a == b
    other = study_noise(model, c, size=51, studies=300, seed=10)
    assert other.trial_floor != a.trial_floor
    big = study_noise(model, c, size=2000, studies=300, seed=9)
    assert all(big.trial_floor[k] < a.trial_floor[k] / 2 for k in a.trial_floor)
    assert big.flow_floor < a.flow_floor / 2


def test_evaluate_prints_the_floor_and_p_beside_the_distances(capsys) -> None:
    code = calibrate_main(["--evaluate", "--holdout", "3", "--holdout-seed", "500",
                           "--studies", "50", "--workers", "2"])
    text = capsys.readouterr().out
    assert code == 0
    assert "floor(51)  p(51)" in text and "TVD of the flows:" in text and "p(51)" in text
    assert "not evidence of a better model" in text
    assert len([line for line in text.splitlines() if line[:5].strip().isdigit()]) == 8


@pytest.mark.parametrize("flag", ["--studies", "--study-size"])
def test_the_bootstrap_sizes_must_be_positive(flag: str, capsys) -> None:
    with pytest.raises(SystemExit):
        calibrate_main(["--evaluate", flag, "0"])
