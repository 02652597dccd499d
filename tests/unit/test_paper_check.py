"""The paper's own published numbers (Secs 7-8) fed through the study analysis.

What is reproduced and what is not is recorded in docs/study.md; this test pins every number
quoted there. Published values are quoted as printed in /work/shared/paper.tex.
"""

from __future__ import annotations

import math

import pytest
from scipy import stats

from services.analysis.study import (
    OUTCOMES,
    ParticipantOutcomes,
    analyze_study,
    likert_test,
    q3_test,
    stuart_maxwell_doc,
)
from services.store import QuestionnaireRecord

N = 51  # participants (Sec 3.2.2)

# Fig 8d as reconstructed from Sec 7.1: control rows × experiment columns, order C, CH, D, DH.
# "35 ... D during the Control phase, 22 ... C, 8 ... CH, 5 remained in D"; "16 ... began in C,
# 4 moved to CH, 2 moved to D, and so forth" — 35 + 16 = 51, so control CH and DH are empty and
# the C row's remaining 10 stay in C (read as C → C; C → DH is the only other place they fit).
PAPER_TABLE = [[10, 4, 2, 0], [0, 0, 0, 0], [22, 8, 5, 0], [0, 0, 0, 0]]
PUBLISHED_SM = 68.125
# Adjacent trials: (statistic, p) as printed in Sec 7.2; their paired tables are not published.
PUBLISHED_PAIRS = {(4, 5): (12.39, 0.0062), (5, 6): (9.48, 0.0087), (6, 7): (2.57, 0.277)}
PUBLISHED_PAIRS[(7, 8)] = (0.44, 0.801)
# Sec 8: Q3 counts and its χ²; the Likert means and t values.
Q3_COUNTS = {"Yes": 34, "No": 8, "Maybe": 9}
PUBLISHED_Q3 = (11.368, 0.0034)
PUBLISHED_T = {"q1": (3.49, -6.831), "q2": (6.86, 2.565), "q4": (6.41, 2.251), "q5": (8.35, 12.370)}
PUBLISHED_P = {"q2": 0.0134, "q4": 0.0288}  # Q1 and Q5: "p < 10^-4"


def test_reconstructed_table_does_not_give_the_published_statistic() -> None:
    doc = stuart_maxwell_doc(PAPER_TABLE)
    assert doc["statistic"] == pytest.approx(27.0, abs=1e-9)
    assert doc["df"] == 2 and doc["categories_kept"] == ["C", "CH", "D"]
    assert doc["p"] == pytest.approx(1.3710e-6, rel=1e-3)
    assert doc["p"] > 1e-8  # the paper: p < 1e-8
    # No reading of "and so forth" helps: moving k of C → C to C → DH gives 27 + k ≤ 37.
    for k in range(11):
        table = [[10 - k, 4, 2, k], *PAPER_TABLE[1:]]
        assert stuart_maxwell_doc(table)["statistic"] == pytest.approx(27.0 + k)
    # The published statistic is self-consistent with its p only: χ²(2) tail at 68.125.
    assert stats.chi2.sf(PUBLISHED_SM, 2) < 1e-8


def test_the_table_through_the_whole_pipeline() -> None:
    """51 participants whose phases realise the table give back the table and the same test."""
    parts = []
    for i, row in enumerate(PAPER_TABLE):
        for j, count in enumerate(row):
            for _ in range(count):
                trials = [OUTCOMES[i]] * 3 + [OUTCOMES[j]] * 5
                parts.append(
                    ParticipantOutcomes(
                        f"P{len(parts) + 1:02d}",
                        f"s{len(parts)}",
                        "complete",
                        dict(enumerate(trials, 1)),
                    )
                )
    doc = analyze_study(parts)
    assert doc["participants"] == N
    assert doc["contingency"]["table"] == PAPER_TABLE
    assert doc["contingency"]["row_totals"] == [16, 0, 35, 0]
    assert doc["contingency"]["column_totals"] == [32, 12, 7, 0]
    flows = {(f["from"], f["to"]): f["count"] for f in doc["flows"]}
    assert flows[("D", "C")] == 22 and flows[("D", "CH")] == 8 and flows[("D", "D")] == 5
    assert max(flows, key=flows.get) == ("D", "C")  # the text says the largest is D → D
    assert doc["stuart_maxwell"]["control_vs_experiment"]["statistic"] == pytest.approx(27.0)


def test_adjacent_pair_p_values_match_their_statistics() -> None:
    """The tables are unpublished; each printed p is the χ² tail of its X² at df 3, 2, 2, 2."""
    dfs = {(4, 5): 3, (5, 6): 2, (6, 7): 2, (7, 8): 2}
    for pair, (x2, p) in PUBLISHED_PAIRS.items():
        assert stats.chi2.sf(x2, dfs[pair]) == pytest.approx(p, rel=1e-2)
        other = 5 - dfs[pair]  # the other plausible df does not fit
        assert abs(stats.chi2.sf(x2, other) - p) > 0.001


def test_q3_counts_do_not_give_the_published_chi2() -> None:
    answers = [k for k, n in Q3_COUNTS.items() for _ in range(n)]
    doc = q3_test(answers)
    assert doc["n"] == N and doc["counts"] == Q3_COUNTS
    assert doc["chi2"] == pytest.approx(434 / 17)  # 25.529
    assert doc["p"] == pytest.approx(2.860e-6, rel=1e-3)
    assert doc["cohens_w"] == pytest.approx(0.7075, abs=1e-4)
    assert doc["cramers_v"] == pytest.approx(0.5003, abs=1e-4)
    x2, p = PUBLISHED_Q3
    assert stats.chi2.sf(x2, 2) == pytest.approx(p, abs=5e-5)  # self-consistent p
    # No three counts summing to 51 give 11.368: 17·(χ² + 51) must be an integer sum of squares.
    assert not any(
        abs(stats.chisquare([a, b, N - a - b]).statistic - x2) < 5e-4
        for a in range(N + 1)
        for b in range(N + 1 - a)
    )
    # It is exactly the χ² of 57 answers split 25/25/7 (or 31/13/13).
    assert stats.chisquare([25, 25, 7]).statistic == pytest.approx(x2, abs=5e-4)


def likert_sample(n: int, total: int, sumsq: int) -> list[int]:
    """n integers in 1..10 with the given sum and sum of squares (greedy spreading)."""
    base, extra = divmod(total, n)
    xs = [base + 1] * extra + [base] * (n - extra)
    current = sum(x * x for x in xs)
    while current < sumsq:
        # Moving one unit from value a to value b ≥ a adds 2(b − a + 1) to the sum of squares.
        moves = [
            (2 * (xs[j] - xs[i] + 1), i, j)
            for i in range(n)
            for j in range(n)
            if i != j and 1 < xs[i] <= xs[j] < 10 and 2 * (xs[j] - xs[i] + 1) <= sumsq - current
        ]
        gain, i, j = max(moves)
        xs[i], xs[j], current = xs[i] - 1, xs[j] + 1, current + gain
    assert current == sumsq
    return xs


def _t(n: int, total: int, sumsq: int) -> float:
    var = (sumsq - total * total / n) / (n - 1)
    return (total / n - 5.5) / math.sqrt(var / n)


@pytest.mark.parametrize("key", ["q1", "q2", "q4", "q5"])
def test_t_tests_are_consistent_with_51_integer_answers(key: str) -> None:
    """Raw answers are unpublished: find 51 ratings with the printed mean whose t rounds to the
    printed t, and run them through the analysis."""
    mean, t_pub = PUBLISHED_T[key]
    total = round(mean * N)
    # Sums of squares have the parity of the sum; pick the one whose t is nearest the paper's.
    sumsq = min(
        range(total * total // N + 1, 10 * total + 1),
        key=lambda s: math.inf if (s - total) % 2 else abs(_t(N, total, s) - t_pub),
    )
    doc = likert_test(likert_sample(N, total, sumsq))
    assert round(doc["mean"], 2) == mean
    assert round(doc["t"], 3) == t_pub
    assert doc["df"] == N - 1
    if key in PUBLISHED_P:
        assert round(doc["p"], 4) == PUBLISHED_P[key]
    else:
        assert doc["p"] < 1e-4
    assert doc["cohens_d"] == pytest.approx(t_pub / math.sqrt(N), abs=1e-3)


def test_fig_8a_percentages_are_counts_out_of_51() -> None:
    printed = {70.59: 36, 68.63: 35, 43.14: 22, 86.27: 44, 11.76: 6, 1.96: 1}
    for pct, count in printed.items():
        assert round(100 * count / N, 2) == pct
    # Trial 8 (C 86.27 %, CH 11.76 %, D 1.96 %) accounts for all 51: "C + CH exceeded 90 %".
    assert sum((44, 6, 1)) == N and (44 + 6) / N > 0.9


def test_questionnaire_records_through_the_pipeline() -> None:
    recs = [
        QuestionnaireRecord(f"P{i:02d}", 5, 5 + (i % 2), q3, 6, 8)
        for i, q3 in enumerate(k for k, n in Q3_COUNTS.items() for _ in range(n))
    ]
    parts = [ParticipantOutcomes(r.participant, "s", "complete", {1: "D"}) for r in recs]
    doc = analyze_study(parts, recs)["questionnaire"]
    assert doc["q3"]["chi2"] == pytest.approx(434 / 17)
    assert "zero spread" in doc["q1"]["error"]
