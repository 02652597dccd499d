"""The counterbalanced O orders: a cyclic Latin square of the protocol's O order with its cyclic
relabellings of the options (colour reversal at two), in seeded blocks of n·N_o
(services/model/counterbalance.py, docs/study.md)."""

from __future__ import annotations

from collections import Counter

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.counterbalance import (
    block_problem,
    block_size,
    latin_block,
    position_counts,
    relabelled,
    reversed_colours,
    roster_orders,
)
from services.model.protocol import default_schedule, order_of

# The paper's option set (the defaults: every call as the paper's study makes it) and three
OPTION_SETS = [("red", "blue"), ("red", "blue", "green")]


def _bases(names):
    return st.lists(st.sampled_from(names), min_size=1, max_size=8).map(tuple)


def _transitions(orders, p):
    return Counter((o[p], o[p + 1]) for o in orders)


def _named(names):
    """The option set as the calls take it: nothing at two options (the paper's defaults)."""
    return {} if names == ("red", "blue") else {"names": names}


@pytest.mark.parametrize("names", OPTION_SETS)
@settings(max_examples=150, deadline=None)
@given(data=st.data(), blocks=st.integers(1, 4), seed=st.integers(0, 2**32))
def test_every_full_block_balances_each_position_and_the_carry_over(names, data, blocks, seed):
    base = data.draw(_bases(names))
    n, k = len(base), len(names)
    orders = roster_orders(base, blocks * block_size(n, k), seed, **_named(names))
    assert len(orders) == blocks * k * n
    for start in range(0, len(orders), k * n):
        block = orders[start : start + k * n]
        # each position: every option n times over the block (red and blue n times each)
        assert position_counts(block, **_named(names)) == [(n,) * k] * n
        # the block is exactly the Latin square's rows (the rotations and their relabellings)
        assert Counter(block) == Counter(latin_block(base, **_named(names)))
        # carry-over: at each consecutive pair, O → O + d as often from every O (at two: R→B
        # as often as B→R, R→R as B→B)
        for p in range(n - 1):
            t = _transitions(block, p)
            for d in range(k):
                steps = {t[(o, relabelled((o,), names, d)[0])] for o in names}
                assert len(steps) == 1, (d, t)
    # every participant's order has the base's mix of options, relabelled
    mixes = {tuple(sorted(Counter(relabelled(base, names, d)).items())) for d in range(k)}
    assert all(tuple(sorted(Counter(o).items())) in mixes for o in orders)
    assert block_problem(base, orders, **_named(names)) is None


@pytest.mark.parametrize("names", OPTION_SETS)
@settings(max_examples=100, deadline=None)
@given(data=st.data(), participants=st.integers(1, 60), seed=st.integers(0, 2**32))
def test_every_multiple_of_the_option_count_of_participants_is_balanced(
    names, data, participants, seed
):
    base = data.draw(_bases(names))
    k = len(names)
    orders = roster_orders(base, participants, seed, **_named(names))
    for m in range(k, participants + 1, k):  # after 2, 4, 6 … participants (3, 6 … at three)
        assert all(len(set(c)) == 1 for c in position_counts(orders[:m], **_named(names)))
    assert block_problem(base, orders, **_named(names)) is None  # a partial last block too


def test_the_papers_protocol_in_a_40_person_study():
    base = order_of(default_schedule())
    assert base == ("blue", "red", "red", "blue", "red")
    assert block_size(len(base)) == 10
    orders = roster_orders(base, 40, seed=7)
    assert position_counts(orders) == [(20, 20)] * 5  # every trial 4-8: 20 red, 20 blue
    # each of the 10 orders of the square 4 times; the paper's own among them
    assert Counter(orders) == Counter({o: 4 for o in latin_block(base)})
    assert base in orders and reversed_colours(base) in orders
    assert roster_orders(base, 40, seed=7) == orders  # the seed makes the roster
    assert roster_orders(base, 40, seed=8) != orders


def test_an_edited_order_is_not_the_latin_square():
    base = ("blue", "red", "red", "blue", "red")
    orders = roster_orders(base, 10, seed=1)
    orders[3] = ("red",) * 5
    problem = block_problem(base, orders)
    assert problem is not None and "slots 1-10" in problem and "RRRRR" in problem
    twice = roster_orders(base, 10, seed=1)
    twice[1] = twice[0] if twice[0] != twice[1] else twice[2]
    assert block_problem(base, twice) is not None  # one order twice, another missing


@pytest.mark.parametrize("names", OPTION_SETS)
@pytest.mark.parametrize("bad", [(), ("yellow",)])
def test_a_bad_base_is_refused(bad, names):
    with pytest.raises(ValueError, match="/".join(names)):
        roster_orders(bad, 4, seed=1, **_named(names))


def test_within_each_pair_either_row_comes_first_by_the_seeds_coin():
    # Each (rotation, reversal) pair's two rows come in a seeded random order: over seeds, the
    # rotation (3 reds of the paper's base; its reversal has 2) leads its pair about half the
    # time at every pair position and every block, and each seed's roster is its own.
    base = ("blue", "red", "red", "blue", "red")
    n_seeds, pairs = 400, 10  # 2 blocks of 5 pairs
    rotation_first = Counter()
    for seed in range(n_seeds):
        orders = roster_orders(base, 2 * pairs, seed)
        assert roster_orders(base, 2 * pairs, seed) == orders  # deterministic per seed
        for k in range(pairs):
            first, second = orders[2 * k], orders[2 * k + 1]
            assert second == reversed_colours(first)  # the slots 2k+1, 2k+2 are one pair
            if Counter(first)["red"] == 3:
                rotation_first[k] += 1
    for k in range(pairs):  # binomial(400, 1/2): sd 10, so 160..240 is 4 sd
        assert 160 <= rotation_first[k] <= 240, (k, rotation_first[k])
    total = sum(rotation_first.values())
    assert 0.46 * n_seeds * pairs <= total <= 0.54 * n_seeds * pairs
