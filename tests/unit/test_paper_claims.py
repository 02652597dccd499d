"""The three computed claims of docs/study.md: margins → 68.125, the unique-equilibrium bias,
Fig 3a's starting opinion."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.analysis.equilibria import find_equilibria
from services.analysis.paper_claims import (
    DEFAULT_Z0,
    PAPER_STATISTIC,
    fig3a_start_dependence,
    statistic_over_margins,
    tables_with_margins,
    unique_equilibrium_bias,
)
from services.analysis.stuart_maxwell import stuart_maxwell
from services.model.dynamics import PairParams


@settings(max_examples=40, deadline=None)
@given(
    rows=st.lists(st.integers(0, 3), min_size=3, max_size=3),
    perm=st.permutations(range(3)),
    shift=st.integers(0, 2),
)
def test_enumeration_is_complete_and_correct(rows: list[int], perm: list[int], shift: int) -> None:
    # Columns: the same total, spread differently (move `shift` from one column to another).
    cols = [rows[i] for i in perm]
    if cols[0] >= shift:
        cols[0] -= shift
        cols[1] += shift
    tables = list(tables_with_margins(rows, cols))
    seen = {t.tobytes() for t in tables}
    assert len(seen) == len(tables)  # no table twice
    for t in tables:
        assert (t >= 0).all()
        assert t.sum(axis=1).tolist() == rows and t.sum(axis=0).tolist() == cols
    # Completeness against brute force over every 3×3 table with cells ≤ max total.
    n = sum(rows)
    brute = 0
    for cells in np.ndindex(*(min(r, c) + 1 for r in rows for c in cols)):
        t = np.array(cells).reshape(3, 3)
        brute += t.sum(axis=1).tolist() == rows and t.sum(axis=0).tolist() == cols
    assert len(tables) == brute and n >= 0


def test_two_by_two_count_has_its_closed_form() -> None:
    # r = (r0, r1), c = (c0, c1): the top-left cell ranges over max(0, r0 - c1) .. min(r0, c0).
    for r0, r1, c0 in [(3, 4, 2), (5, 0, 5), (7, 7, 3)]:
        c1 = r0 + r1 - c0
        count = sum(1 for _ in tables_with_margins((r0, r1), (c0, c1)))
        assert count == min(r0, c0) - max(0, r0 - c1) + 1


def test_margins_reject_bad_totals() -> None:
    with pytest.raises(ValueError, match="equal totals"):
        list(tables_with_margins((1, 2), (2, 2)))
    with pytest.raises(ValueError, match="too many"):
        list(tables_with_margins((20, 20, 20), (20, 20, 20), limit=100))


def test_no_table_with_the_published_margins_gives_68_125() -> None:
    search = statistic_over_margins()
    reconstructed = [[10, 4, 2, 0], [0, 0, 0, 0], [22, 8, 5, 0], [0, 0, 0, 0]]
    assert stuart_maxwell(reconstructed).statistic == pytest.approx(27.0)
    assert search.minimum <= 27.0 <= search.maximum
    assert search.maximum < PAPER_STATISTIC and not search.attainable
    assert search.closest == search.maximum
    assert stuart_maxwell(search.closest_table).statistic == pytest.approx(search.maximum)
    # The search itself can find a statistic that is there.
    assert statistic_over_margins(target=27.0).attainable


def test_unique_equilibrium_bias_brackets_the_count_change() -> None:
    p = PairParams()
    ub = unique_equilibrium_bias(p, tol=1e-6)
    eps = 1e-4
    assert len(find_equilibria(ub.b_unique - eps, ub.b_unique - eps, p)) == 3
    assert len(find_equilibria(ub.b_unique + eps, ub.b_unique + eps, p)) == 1
    below = find_equilibria(ub.b_all_consensus - eps, ub.b_all_consensus - eps, p)
    above = find_equilibria(ub.b_all_consensus + eps, ub.b_all_consensus + eps, p)
    assert not all(e.consensus for e in below) and all(e.consensus for e in above)
    # With the paper's parameters u sits between the two: every equilibrium is a consensus at
    # |b| = u, but there are still three of them (the |b| > u claim is about sign, not number).
    assert ub.b_all_consensus < p.robot.u < ub.b_unique and ub.count_at_u == 3


def test_fig3a_barely_depends_on_the_start() -> None:
    rows = fig3a_start_dependence(grid=21)
    by_start = {r.z0: r for r in rows}
    assert by_start[DEFAULT_Z0].differs_from_default == 0.0
    # A 1e-6 lean either way is the same map (the map is symmetric under z → −z, b → −b).
    assert by_start[(-1e-6, 0.0)].differs_from_default == 0.0
    # Committed starts change only cells in the bistable band, a few per cent at most.
    assert all(r.differs_from_default < 0.05 for r in rows)
    assert 0.1 < by_start[DEFAULT_Z0].consensus_share < 0.4
