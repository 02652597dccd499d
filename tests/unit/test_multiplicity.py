"""Holm and Bonferroni adjustments of a family of p-values (services.analysis.multiplicity)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.analysis.multiplicity import CORRECTIONS, adjust

P = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)
FAMILY = st.lists(P, min_size=1, max_size=12)


def test_a_worked_example() -> None:
    # Sorted: 0.005·4 = 0.02, 0.01·3 = 0.03, 0.03·2 = 0.06, 0.04·1 = 0.04 → max so far 0.06.
    assert adjust([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert adjust([0.01, 0.04, 0.03, 0.005], "bonferroni") == pytest.approx(
        [0.04, 0.16, 0.12, 0.02]
    )
    assert adjust([0.01, 0.5], "none") == [0.01, 0.5]
    assert adjust([0.3, 0.6]) == [0.6, 0.6]  # capped by the step-down's running maximum
    assert adjust([0.9, 0.8]) == [1.0, 1.0]
    assert adjust([]) == []


@given(FAMILY)
def test_holm_is_monotone_bounded_and_bonferroni_at_the_smallest(p: list[float]) -> None:
    q = adjust(p, "holm")
    m = len(p)
    assert len(q) == m
    for i in range(m):
        assert p[i] <= q[i] <= 1.0
        for j in range(m):
            if p[i] <= p[j]:
                assert q[i] <= q[j]  # adjusted p keep the raw p's order
    smallest = min(range(m), key=lambda i: p[i])
    assert q[smallest] == pytest.approx(min(1.0, m * p[smallest]))


@given(FAMILY)
def test_holm_never_exceeds_bonferroni_and_none_is_the_identity(p: list[float]) -> None:
    holm, bonf = adjust(p, "holm"), adjust(p, "bonferroni")
    assert all(h <= b + 1e-12 for h, b in zip(holm, bonf, strict=True))
    assert adjust(p, "none") == p


@given(FAMILY, st.floats(min_value=1e-6, max_value=0.5))
def test_holm_rejects_what_its_step_down_rejects(p: list[float], alpha: float) -> None:
    """Holm's adjusted p < α exactly for the hypotheses the step-down procedure rejects."""
    m = len(p)
    order = sorted(range(m), key=lambda i: p[i])
    rejected: set[int] = set()
    for rank, i in enumerate(order):
        if p[i] * (m - rank) >= alpha:
            break
        rejected.add(i)
    q = adjust(p, "holm")
    assert {i for i in range(m) if q[i] < alpha} == rejected


def test_the_papers_five_tests_through_holm() -> None:
    """Sec 7's p (control vs experiment "below 1e-8", then 4→5 … 7→8), as docs/study.md quotes."""
    q = adjust([1e-8, 0.0062, 0.0087, 0.277, 0.801])
    assert q == pytest.approx([5e-8, 0.0248, 0.0261, 0.554, 0.801])
    assert [x < 0.05 for x in q] == [True, True, True, False, False]


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError, match="holm, bonferroni, none"):
        adjust([0.1], "bh")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        adjust([0.1, float("nan")])
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        adjust([1.5])
    assert CORRECTIONS == ("holm", "bonferroni", "none")
