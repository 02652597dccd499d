"""The cohort calibration's pieces on tiny problems: CMA-ES in the box, common random numbers,
the Fig 8b flows, the default fitted person, and `nod calibrate-cohort` end to end (seconds)."""

from __future__ import annotations

import tomllib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.cohort.outcomes import cohort_outcomes, flows, load_flows, shares, tvd
from services.cohort.person import FIG8B, FITTED_TRAITS, load_cohort_params
from services.compute.engine import Engine, open_engine
from services.core.config import ConfigError
from services.model.params import NodConfig
from services.sim.calibrate import Check, against_start
from services.sim.calibrate import main as calibrate_main
from services.sim.fit import (
    TRAITS,
    CohortObjective,
    Trait,
    from_unit,
    minimise,
    score,
    to_unit,
    with_traits,
)


@pytest.fixture(scope="module")
def engine() -> Iterator[Engine]:
    with open_engine(workers=2) as e:
        yield e


def test_cma_es_finds_a_minimum_inside_the_box_and_starts_at_x0() -> None:
    optimum = np.array([0.2, 0.7, 0.95])
    x0 = np.array([0.9, 0.1, 1.0])  # on a bound: the first candidate must still be x0 exactly
    asked: list[np.ndarray] = []

    def evaluate(batch: list[np.ndarray]) -> list[float]:
        asked.extend(batch)
        return [float(np.sum((x - optimum) ** 2)) for x in batch]

    x, f = minimise(evaluate, x0, generations=40, popsize=8, sigma0=0.3, seed=4)
    assert np.array_equal(asked[0], x0)
    assert len(asked) == 40 * 8
    assert all(((a >= 0.0) & (a <= 1.0)).all() for a in asked)  # never outside the box
    assert f < 1e-3 and np.allclose(x, optimum, atol=0.03)
    # The seed fixes the search: the same seed and scores ask for the same candidates.
    again: list[np.ndarray] = []

    def evaluate_again(batch: list[np.ndarray]) -> list[float]:
        again.extend(batch)
        return [float(np.sum((x - optimum) ** 2)) for x in batch]

    minimise(evaluate_again, x0, generations=3, popsize=8, sigma0=0.3, seed=4)
    assert all(np.array_equal(a, b) for a, b in zip(asked[:24], again, strict=True))


@given(st.lists(st.floats(0.0, 1.0), min_size=len(TRAITS), max_size=len(TRAITS)))
def test_traits_map_to_their_ranges_and_back(unit: list[float]) -> None:
    values = from_unit(unit)
    for t in TRAITS:
        assert t.low <= values[t.name] <= t.high
    cfg = with_traits(NodConfig(), values)
    assert np.allclose(to_unit(cfg), unit, atol=1e-9)


def test_a_new_trait_is_one_line_of_the_table() -> None:
    extra = (*TRAITS, Trait("reaction_s", 0.1, 0.5))
    cfg = with_traits(NodConfig(), from_unit([0.5] * len(extra), extra))
    assert cfg.participant.reaction_s == pytest.approx(0.3)
    assert to_unit(cfg, extra)[-1] == pytest.approx(0.5)


def test_flows_and_their_distance() -> None:
    # Two people: C in control (2 of 3) then C; D in control then CH (3 of 5).
    cohort = [["C", "C", "D", "C", "C", "C", "D", "C"],
              ["D", "D", "D", "CH", "CH", "CH", "C", "C"]]
    got = flows(cohort)
    assert got["C", "C"] == 0.5 and got["D", "CH"] == 0.5
    assert sum(got.values()) == pytest.approx(1.0)
    paper = load_flows(FIG8B.read_text(), "Fig 8b")
    assert paper["C", "C"] == pytest.approx(10 / 51) and paper["D", "C"] == pytest.approx(22 / 51)
    assert sum(paper.values()) == pytest.approx(1.0)
    assert tvd(got, got) == 0.0 and 0 < tvd(got, paper) <= 1
    with pytest.raises(ValueError, match="flows"):
        load_flows('{"flows": {"C": {"X": 3}}}', "bad")


def test_the_flow_weight_scales_only_the_flows_term() -> None:
    control_c = ["C", "C", "C", "C", "C", "C", "C", "C"]
    control_d = ["D", "D", "D", "C", "C", "C", "C", "C"]
    target_cohort = [control_c, control_d]
    target, target_flows = shares(target_cohort), flows(target_cohort)
    # The second person ends the experiment phase CH, not C: trials 4-6 and a flow differ.
    swapped = [control_c, ["D", "D", "D", "CH", "CH", "CH", "C", "C"]]
    trials = sum(tvd(shares(swapped)[k], w) for k, w in target.items())
    moved = tvd(flows(swapped), target_flows)
    assert moved > 0
    assert score(swapped, target, target_flows) == pytest.approx(trials + moved)
    assert score(swapped, target, target_flows, 3.0) == pytest.approx(trials + 3.0 * moved)
    assert score(target_cohort, target, target_flows, 3.0) == 0.0


def test_a_fit_worse_than_its_start_on_held_out_people_is_called_so() -> None:
    def made(trial: float, flow: float) -> Check:
        return Check(400, 1, {}, {}, {k: trial for k in range(1, 9)}, flow)

    start, good, bad = made(0.05, 0.10), made(0.04, 0.10), made(0.05, 0.30)
    assert good.score(2.0) == pytest.approx(8 * 0.04 + 0.2)
    assert len(against_start(good, start, 2.0)) == 1  # better: nothing to warn of
    worse = against_start(bad, start, 2.0)
    assert "WORSE than its start" in worse[-1] and "score 0.600 against the fit's 1.000" in worse[0]


def test_common_random_numbers_and_a_perfect_score_for_the_start(engine: Engine) -> None:
    cfg = NodConfig()
    own = cohort_outcomes(engine, cfg, 11, 3)
    objective = CohortObjective(engine, cfg, shares(own), flows(own), n=3, seed=11)
    x0 = to_unit(cfg)
    other = np.clip(x0 + 0.3, 0, 1)
    scores = objective([x0, other, x0])
    assert scores[0] == 0.0 and scores[2] == 0.0  # the same people, the same traits: identical
    assert scores[1] == pytest.approx(score(objective.cohorts([other])[0], shares(own),
                                            flows(own)))


def test_the_default_person_is_the_shipped_fit(tmp_path: Path) -> None:
    shipped = tomllib.loads(FITTED_TRAITS.read_text())["participant"]
    person = load_cohort_params(None).participant
    assert all(getattr(person, k) == pytest.approx(v) for k, v in shipped.items())
    assert person != NodConfig().participant
    mine = tmp_path / "mine.toml"
    mine.write_text("[participant]\nspeed = 0.5\n[protocol]\nmax_attempts = 2\n")
    cfg = load_cohort_params(mine)
    assert cfg.participant.speed == 0.5 and cfg.protocol.max_attempts == 2
    assert cfg.participant.trust0 == pytest.approx(shipped["trust0"])  # the rest stays fitted
    mine.write_text("[participant]\nspeeed = 0.5\n")
    with pytest.raises(ConfigError, match="speeed"):
        load_cohort_params(mine)


def test_calibrate_cohort_fits_checks_on_other_people_and_says_how(tmp_path: Path,
                                                                    capsys) -> None:
    out = tmp_path / "fit.toml"
    code = calibrate_main(["--participants", "2", "--generations", "1", "--popsize", "2",
                           "--holdout", "3", "--holdout-seed", "500", "--workers", "2",
                           "--flow-weight", "2.5", "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0
    assert "generation 1/1" in text and "3 participants (seeds 500..502)" in text
    assert "D → C" in text and "TVD of the flows" in text
    assert len([line for line in text.splitlines() if line[:5].strip().isdigit()]) == 8
    written = out.read_text()
    assert "--participants 2 --generations 1" in written and "seeds 1..2" in written
    assert "(Σ trial TVD + 2.5 × flow TVD)" in written
    assert "its start on the same people: Σ trial TVD" in text  # the fit against where it began
    assert "its start on the same people" in written
    assert "held out: 3 participants, seeds 500..502: TVD per trial 1-8 =" in written
    fitted = load_cohort_params(out).participant  # the file is a --params file
    assert all(t.low <= getattr(fitted, t.name) <= t.high for t in TRAITS)


def test_held_out_people_must_not_be_the_fits(capsys) -> None:
    assert calibrate_main(["--participants", "10", "--seed", "1", "--holdout-seed", "5"]) == 2
    assert "must not be the fit's" in capsys.readouterr().err


def test_traits_fits_only_the_named_ones_and_holds_the_rest(tmp_path: Path, capsys) -> None:
    start = load_cohort_params(None).participant
    out = tmp_path / "fit.toml"
    code = calibrate_main(["--participants", "2", "--generations", "1", "--popsize", "3",
                           "--sigma0", "0.5", "--holdout", "2", "--holdout-seed", "500",
                           "--workers", "1", "--traits", "contrarian_share,trust0",
                           "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0 and "fitting 2 traits" in text
    assert "traits: contrarian_share = " in text and ", trust0 = " in text
    fitted = load_cohort_params(out).participant
    named = {"contrarian_share", "trust0"}
    for t in TRAITS:  # every other trait is the start's, written as it was
        if t.name not in named:
            assert getattr(fitted, t.name) == pytest.approx(getattr(start, t.name), abs=1e-4)
    assert "over 2 traits" in out.read_text()


@pytest.mark.parametrize("traits", ["speeed", "trust0,trust0", ","])
def test_bad_traits_are_one_line(traits: str, capsys) -> None:
    with pytest.raises(SystemExit):
        calibrate_main(["--traits", traits, "--evaluate"])
    err = capsys.readouterr().err
    assert "--traits" in err and "name fitted traits once each" in err
