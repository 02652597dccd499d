"""Counterbalanced O orders for a study's participants (docs/study.md, "Counterbalancing").

The protocol's consensus trials keep their gaze levels in the paper's rising order (minimal →
extreme: the progression is the manipulation, paper Remark 5 and Q4); what is counterbalanced is
O, the option the robot is biased toward in each of them, and with it the side the eyes look at
(the gaze always looks toward O). One block of 2n participants, for n consensus trials and the
protocol's own O sequence `base`:

- the n cyclic rotations of `base` (a Latin square: at each trial position every element of the
  base pattern — its colour and whether it repeats or switches the previous O — appears once);
- each followed by its colour reversal (red ↔ blue).

Over a block every position sees red and blue n times each, each participant's order has the
base's mix (e.g. 3 of one colour, 2 of the other), and the carry-over is balanced: at every pair
of consecutive trials, red → blue occurs as often as blue → red, and red → red as blue → blue.
The block's rows come as n (rotation, reversal) pairs in a seeded random order, each pair's two
rows in a seeded random order, so after any even number of participants of a block every
position is balanced too, and the sequence of orders is not predictable from the slot number.
"""

from __future__ import annotations

import random
from collections import Counter
from collections.abc import Sequence

from services.model.geometry import Colour
from services.model.protocol import Order

FLIP: dict[Colour, Colour] = {"red": "blue", "blue": "red"}


def reversed_colours(order: Sequence[Colour]) -> Order:
    """The order with red and blue swapped."""
    return tuple(FLIP[o] for o in order)


def block_size(n: int) -> int:
    """Participants in one balanced block, for n consensus trials (2n)."""
    return 2 * n


def latin_pairs(base: Sequence[Colour]) -> list[tuple[Order, Order]]:
    """The block's n (rotation of `base`, its colour reversal) pairs, rotation k at index k."""
    _check(base)
    n = len(base)
    rotations = [tuple(base[(p + k) % n] for p in range(n)) for k in range(n)]
    return [(r, reversed_colours(r)) for r in rotations]


def latin_block(base: Sequence[Colour]) -> list[Order]:
    """One block's 2n orders, unshuffled: rotation 0 and its reversal, then rotation 1 and so on."""
    return [row for pair in latin_pairs(base) for row in pair]


def roster_orders(base: Sequence[Colour], participants: int, seed: int) -> list[Order]:
    """The orders of slots 1..participants: blocks of 2n, each block's pairs in seeded order.

    Deterministic for (base, participants, seed) on one Python; the study file stores the
    result, so a roster never depends on being regenerated.
    """
    if participants < 1:
        raise ValueError(f"a roster needs at least 1 participant, got {participants}")
    rng = random.Random(seed)
    out: list[Order] = []
    while len(out) < participants:
        pairs = latin_pairs(base)
        rng.shuffle(pairs)
        for a, b in pairs:
            out.extend((a, b) if rng.random() < 0.5 else (b, a))
    return out[:participants]


def position_counts(orders: Sequence[Sequence[Colour]]) -> list[tuple[int, int]]:
    """(red, blue) counts at each position of equally long orders."""
    if not orders:
        return []
    n = len(orders[0])
    return [
        (sum(o[p] == "red" for o in orders), sum(o[p] == "blue" for o in orders)) for p in range(n)
    ]


def block_problem(base: Sequence[Colour], orders: Sequence[Sequence[Colour]]) -> str | None:
    """Why `orders` (slots 1..N in order) are not the Latin-square blocks of `base`, or None.

    Each full block must hold exactly the 2n orders of `latin_block(base)` (in any order), the
    last, partial block some of them, each at most once. Checked by content, not by
    regenerating the shuffle, so a roster stays valid whatever the random module does later.
    """
    size = block_size(len(base))
    rows = Counter(latin_block(base))
    for start in range(0, len(orders), size):
        have = Counter(tuple(o) for o in orders[start : start + size])
        extra = have - rows
        if extra:
            bad = next(iter(extra))
            return (
                f"slots {start + 1}-{start + size} are not a Latin-square block of "
                f"{_letters(base)}: {_letters(bad)} is not one of its orders (or comes more "
                "often than the block holds it)"
            )
    return None


def _letters(order: Sequence[Colour]) -> str:
    return "".join(o[0].upper() for o in order)


def _check(base: Sequence[Colour]) -> None:
    if not base or any(o not in FLIP for o in base):
        raise ValueError(f"a base order is one or more of red/blue, got {list(base)}")
