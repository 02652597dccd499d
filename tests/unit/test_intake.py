"""Bounded intake: the token bucket and caps never admit more than promised, and count the rest."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.intake import NS_PER_S, IntakeLimit

# Arrival gaps (ns): floods (0), camera-like gaps, long silences; and an occasional step back.
gaps = st.lists(
    st.one_of(
        st.just(0),
        st.integers(0, 5_000_000),
        st.integers(0, 3 * NS_PER_S),
        st.integers(-2_000_000, -1),
    ),
    min_size=1,
    max_size=400,
)
limits = st.builds(
    IntakeLimit,
    burst=st.integers(1, 60),
    per_s=st.integers(0, 500),
    per_scope=st.integers(0, 10**6),
    total=st.integers(0, 10**6),
)


def arrivals(start: int, steps: list[int]) -> list[int]:
    out, t = [], start
    for gap in steps:
        t += gap
        out.append(t)
    return out


@settings(max_examples=300, deadline=None)
@given(limit=limits, steps=gaps, start=st.integers(0, 10**15))
def test_never_more_than_burst_plus_rate_over_any_window_and_every_drop_counted(
    limit, steps, start
):
    times = arrivals(start, steps)
    taken = []  # admitted arrivals, on the bucket's clock (a step back counts as no time)
    clock = times[0]
    for t in times:
        clock = max(clock, t)
        if limit.admit(t) is None:
            taken.append(clock)
    assert limit.accepted == len(taken)
    assert limit.dropped == len(times) - len(taken)  # exactly the refused ones
    assert limit.accepted <= limit.total
    # Every window between two admitted arrivals i <= j: (j - i + 1) * 1 s <= burst * 1 s +
    # per_s * (t_j - t_i). With f(k) = k * 1 s - per_s * t_k that is f(j) - f(i) + 1 s <=
    # burst * 1 s: keep the lowest f(i) so far.
    lowest = None
    for k, t in enumerate(taken):
        f = k * NS_PER_S - limit.per_s * t
        lowest = f if lowest is None else min(lowest, f)
        assert f - lowest + NS_PER_S <= limit.burst * NS_PER_S

@settings(max_examples=200, deadline=None)
@given(
    limit=limits,
    scopes=st.lists(st.tuples(st.integers(0, 4), st.integers(1, 40)), min_size=1, max_size=12),
)
def test_caps_per_scope_and_in_all_hold_in_a_flood_of_scopes(limit, scopes):
    t = 0
    for scope, n in scopes:
        before = limit.accepted
        for _ in range(n):
            t += NS_PER_S  # plenty of tokens: only the caps can refuse
            limit.admit(t, scope)
        assert limit.accepted - before <= limit.per_scope
    assert limit.accepted <= limit.total
    assert limit.accepted + limit.dropped == sum(n for _, n in scopes)


def test_a_flood_gets_the_burst_then_the_rate_and_the_reasons_say_which_cap():
    limit = IntakeLimit(burst=5, per_s=10, per_scope=8, total=9, scope_label="per trial")
    assert [limit.admit(0, "a") for _ in range(6)] == [None] * 5 + [
        "rate limit (burst 5, 10/s)"
    ]
    assert limit.admit(NS_PER_S // 10, "a") is None  # one token a tenth of a second later
    assert limit.admit(NS_PER_S // 10, "a") is not None
    assert limit.admit(10 * NS_PER_S, "a") is None
    assert limit.admit(10 * NS_PER_S, "a") is None  # 8 in scope "a" now
    assert limit.admit(10 * NS_PER_S, "a") == "cap of 8 per trial"
    assert limit.admit(10 * NS_PER_S, "b") is None  # a new scope: 9 in all
    assert limit.admit(20 * NS_PER_S, "c") == "cap of 9 in all"
    assert (limit.accepted, limit.dropped) == (9, 4)
    assert limit.describe() == "burst 5, then 10/s; 8 per trial; 9 in all"


@pytest.mark.parametrize("bad", [{"burst": 0}, {"per_s": -1}, {"per_scope": -1}, {"total": -1}])
def test_refuses_limits_that_mean_nothing(bad):
    with pytest.raises(ValueError, match="intake limit"):
        IntakeLimit(**{"burst": 1, "per_s": 1, "per_scope": 1, "total": 1, **bad})
