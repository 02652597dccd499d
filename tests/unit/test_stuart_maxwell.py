"""Stuart-Maxwell test (SPEC §7) against independent computations."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from services.analysis.stuart_maxwell import mcnemar, stuart_maxwell

COUNTS = st.integers(min_value=0, max_value=40)


@given(a=COUNTS, b=COUNTS, c=COUNTS, d=COUNTS)
def test_two_by_two_is_mcnemar(a: int, b: int, c: int, d: int) -> None:
    assume(b + c > 0)
    res = stuart_maxwell([[a, b], [c, d]])
    assert res.df == 1
    assert res.statistic == pytest.approx(mcnemar(b, c), rel=1e-12, abs=1e-12)
    assert res.statistic == pytest.approx((b - c) ** 2 / (b + c), rel=1e-12, abs=1e-12)
    assert res.p == pytest.approx(chi2.sf(res.statistic, 1))


@settings(max_examples=60)
@given(k=st.integers(3, 5), data=st.data())
def test_invariant_to_the_category_left_out(k: int, data: st.DataObject) -> None:
    table = np.array(
        data.draw(st.lists(st.lists(COUNTS, min_size=k, max_size=k), min_size=k, max_size=k))
    )
    try:
        ref = stuart_maxwell(table)
    except ValueError:
        assume(False)
    for drop in ref.kept:
        assert stuart_maxwell(table, drop=drop).statistic == pytest.approx(
            ref.statistic, rel=1e-8, abs=1e-9
        )


def test_hand_computed_three_by_three() -> None:
    # Control (rows) → experiment (columns), categories C, CH, D, DH: the flows stated in
    # Sec 7.1 (D: 22→C, 8→CH, 5→D; C: 4→CH, 2→D, so 10→C). CH and DH rows are empty and DH
    # is empty in both margins, so it is dropped: d = (16−32, 0−12) over (C, CH),
    # S = [[28, −4], [−4, 12]], X² = dᵀS⁻¹d = 8640/320 = 27.
    table = [[10, 4, 2, 0], [0, 0, 0, 0], [22, 8, 5, 0], [0, 0, 0, 0]]
    res = stuart_maxwell(table)
    assert res.kept == (0, 1, 2)
    assert res.df == 2
    assert res.statistic == pytest.approx(27.0)
    assert res.p == pytest.approx(np.exp(-27.0 / 2))  # χ²(2) tail is exp(−x/2)


def test_empty_categories_are_dropped() -> None:
    small = [[5, 3, 1], [2, 6, 4], [0, 1, 7]]
    padded = [[5, 0, 3, 1], [0, 0, 0, 0], [2, 0, 6, 4], [0, 0, 1, 7]]
    a, b = stuart_maxwell(small), stuart_maxwell(padded)
    assert a.statistic == pytest.approx(b.statistic) and a.df == b.df == 2
    assert b.kept == (0, 2, 3)


def test_symmetric_table_gives_zero() -> None:
    res = stuart_maxwell([[5, 2, 1], [2, 5, 3], [1, 3, 5]])
    assert res.statistic == pytest.approx(0.0, abs=1e-12)
    assert res.p == pytest.approx(1.0)


def test_as_dict_fields() -> None:
    doc = stuart_maxwell([[1, 4], [9, 2]]).as_dict()
    assert {"statistic", "df", "p"} <= set(doc)


@pytest.mark.parametrize(
    "table, match",
    [
        ([[3, 0], [0, 4]], "singular"),  # no discordant pairs
        ([[3, 1, 0], [2, 4, 0], [0, 0, 5]], "singular"),  # category 3 never changes
        ([[1, 2], [3]], "ragged"),
        ([[1, -2], [3, 4]], ">= 0"),
        ([[1, 2, 3], [4, 5, 6]], "square"),
        ([], "non-empty"),
        ([[1, "a"], [2, 3]], "numbers"),
        ([[float("nan"), 1], [2, 3]], "finite"),
        ([[4, 0], [0, 0]], "at least 2"),
        ("[[1,2],[3,4]]", "list of rows"),
    ],
)
def test_bad_tables_raise(table, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        stuart_maxwell(table)


def test_drop_must_be_a_kept_category() -> None:
    with pytest.raises(ValueError, match="cannot drop"):
        stuart_maxwell([[1, 2, 0], [3, 4, 0], [0, 0, 0]], drop=2)
