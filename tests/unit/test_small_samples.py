"""Honest small samples: every test says whether its approximation holds, and gives an exact p
(checked against scipy's exact tests and brute force) with a caveat the report prints beside
the p when it does not."""

from __future__ import annotations

import itertools

import numpy as np
from scipy import stats

from services.analysis.exact import (
    marginal_homogeneity_exact,
    multinomial_exact,
    sign_flip_exact,
)
from services.analysis.stuart_maxwell import stuart_maxwell
from services.analysis.study import likert_test, q3_test, stuart_maxwell_doc
from services.analysis.study_report import _sm_short


def test_the_exact_2x2_test_is_the_exact_mcnemar() -> None:
    for b, c in ((1, 6), (0, 3), (4, 4), (2, 9)):
        table = np.array([[3, b], [c, 2]])
        assert np.isclose(marginal_homogeneity_exact(table, [0, 1]),
                          stats.binomtest(b, b + c, 0.5).pvalue)


def test_the_exact_stuart_maxwell_agrees_with_the_chi2_on_a_large_table() -> None:
    table = np.random.default_rng(0).integers(0, 8, (4, 4))
    result = stuart_maxwell(table)
    exact = marginal_homogeneity_exact(table, result.kept)
    assert exact is not None and abs(exact - result.p) < 0.02


def test_the_exact_multinomial_and_sign_flip_match_brute_force() -> None:
    for observed in ([3, 0, 0], [2, 1, 0], [5, 2, 1], [1, 1, 1]):
        n = sum(observed)
        pmf = stats.multinomial(n, [1 / 3] * 3).pmf
        mine = pmf(observed)
        brute = sum(pmf(c) for c in itertools.product(range(n + 1), repeat=3)
                    if sum(c) == n and pmf(c) <= mine * (1 + 1e-9))
        assert np.isclose(multinomial_exact(observed), brute)
    assert sign_flip_exact([9, 8, 9], 5.5) == 0.25  # the smallest p three answers can give
    assert sign_flip_exact([7, 4, 5.5], 5.5) == 1.0


def test_two_people_get_a_caveat_beside_their_p_and_many_do_not() -> None:
    two = np.zeros((4, 4), dtype=int)
    two[0, 2] = two[2, 0] = 1  # C→D and D→C: two discordant pairs
    doc = stuart_maxwell_doc(two)
    assert "p" in doc and doc["approximation_ok"] is False  # the old keys stay
    assert doc["p_exact"] == 1.0 and "2 discordant pair(s)" in doc["caveat"]
    assert doc["caveat"] in _sm_short(doc, "none")
    many = np.array([[20, 8, 3, 1], [2, 9, 4, 0], [7, 1, 12, 5], [2, 3, 1, 6]])
    big = stuart_maxwell_doc(many)
    assert big["approximation_ok"] is True and "caveat" not in big
    assert " — " not in _sm_short(big, "none")


def test_questionnaire_tests_on_few_answers_say_so() -> None:
    few = likert_test([9, 8, 9])
    assert few["approximation_ok"] is False and few["p_exact"] == 0.25
    assert few["p"] < 0.05 < few["p_exact"]  # the t-test's p claims what three answers cannot
    assert "only 3 answers" in few["caveat"]
    assert likert_test([9, 8, 9, 7, 6, 8])["approximation_ok"] is True
    q3 = q3_test(["Yes", "Yes", "Yes", "No"])
    assert q3["approximation_ok"] is False and "expected count 1.33 < 5" in q3["caveat"]
    assert q3_test(["Yes"] * 7 + ["No"] * 5 + ["Maybe"] * 6)["approximation_ok"] is True
