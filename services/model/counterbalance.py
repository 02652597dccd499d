"""Counterbalanced O orders for a study's participants (docs/study.md, "Counterbalancing").

The protocol's consensus trials keep their gaze levels in the paper's rising order (minimal →
extreme: the progression is the manipulation, paper Remark 5 and Q4); what is counterbalanced is
O, the option the robot is biased toward in each of them, and with it the box the eyes look at
(the gaze always looks toward O). Over an option set of N_o names (the paper's: red, blue), one
block of n·N_o participants, for n consensus trials and the protocol's own O sequence `base`:

- the n cyclic rotations of `base` (a Latin square over positions: at each trial position every
  element of the base pattern — its option and whether it repeats or changes the previous O —
  appears once);
- each under the N_o cyclic relabellings of the options, name k → name k + j (mod N_o), j = 0
  … N_o − 1 (a Latin square over options: each rotation's entry at a position takes every
  option once). At N_o = 2 these are the identity and the colour reversal (red ↔ blue), the
  paper's design, row for row.

Over a block every position sees each option n times, each participant's order has the base's
mix relabelled (e.g. 3 of one option, 2 of another), and the carry-over is balanced: at every
pair of consecutive trials, for every step d, O → O + d occurs as often from each option O
(at two options: red → blue as often as blue → red, red → red as blue → blue). The block's rows
come as n groups (a rotation with its N_o relabellings) in a seeded random order, each group's
rows in a seeded random order, so after any multiple of N_o participants of a block every
position is balanced too, and the sequence of orders is not predictable from the slot number.
Two options keep the paper's draw for a group's order (one coin: the pair as made or swapped),
so a paper study's roster is the one its seed always gave.
"""

from __future__ import annotations

import random
from collections import Counter
from collections.abc import Sequence

from services.model.geometry import COLOURS, Colour
from services.model.protocol import Order

FLIP: dict[Colour, Colour] = {"red": "blue", "blue": "red"}
Names = tuple[str, ...]  # one order of option names (at two options, an `Order` of colours)


def reversed_colours(order: Sequence[Colour]) -> Order:
    """The order with red and blue swapped."""
    return tuple(FLIP[o] for o in order)


def relabelled(order: Sequence[str], names: Sequence[str], step: int) -> Names:
    """The order with each option name k replaced by name k + step (mod N_o)."""
    n = len(names)
    return tuple(names[(names.index(o) + step) % n] for o in order)


def block_size(n: int, n_options: int = 2) -> int:
    """Participants in one balanced block, for n consensus trials over N_o options (n·N_o)."""
    return n_options * n


def latin_groups(base: Sequence[str], names: Sequence[str] = COLOURS) -> list[list[Names]]:
    """The block's n groups: rotation k of `base` and its N_o relabellings, at index k."""
    _check(base, names)
    n = len(base)
    rotations = [tuple(base[(p + k) % n] for p in range(n)) for k in range(n)]
    return [[relabelled(r, names, j) for j in range(len(names))] for r in rotations]


def latin_block(base: Sequence[str], names: Sequence[str] = COLOURS) -> list[Names]:
    """One block's n·N_o orders, unshuffled: rotation 0 and its relabellings, then the next."""
    return [row for group in latin_groups(base, names) for row in group]


def roster_orders(
    base: Sequence[str], participants: int, seed: int, names: Sequence[str] = COLOURS
) -> list[Names]:
    """The orders of slots 1..participants: blocks of n·N_o, each block's groups in seeded order.

    Deterministic for (base, participants, seed, names) on one Python; the study file stores the
    result, so a roster never depends on being regenerated.
    """
    if participants < 1:
        raise ValueError(f"a roster needs at least 1 participant, got {participants}")
    rng = random.Random(seed)
    out: list[Names] = []
    while len(out) < participants:
        groups = latin_groups(base, names)
        rng.shuffle(groups)
        for group in groups:
            if len(group) == 2:  # the paper's draw: one coin per pair, as its rosters had it
                a, b = group
                out.extend((a, b) if rng.random() < 0.5 else (b, a))
            else:
                rng.shuffle(group)
                out.extend(group)
    return out[:participants]


def position_counts(
    orders: Sequence[Sequence[str]], names: Sequence[str] = COLOURS
) -> list[tuple[int, ...]]:
    """How often each option (in `names` order) is O at each position of equally long orders."""
    if not orders:
        return []
    n = len(orders[0])
    return [tuple(sum(o[p] == name for o in orders) for name in names) for p in range(n)]


def block_problem(
    base: Sequence[str], orders: Sequence[Sequence[str]], names: Sequence[str] = COLOURS
) -> str | None:
    """Why `orders` (slots 1..N in order) are not the Latin-square blocks of `base`, or None.

    Each full block must hold exactly the n·N_o orders of `latin_block(base, names)` (in any
    order), the last, partial block some of them, each at most once. Checked by content, not by
    regenerating the shuffle, so a roster stays valid whatever the random module does later.
    """
    size = block_size(len(base), len(names))
    rows = Counter(latin_block(base, names))
    for start in range(0, len(orders), size):
        have = Counter(tuple(o) for o in orders[start : start + size])
        extra = have - rows
        if extra:
            bad = next(iter(extra))
            return (
                f"slots {start + 1}-{start + size} are not a Latin-square block of "
                f"{letters(base, names)}: {letters(bad, names)} is not one of its orders (or "
                "comes more often than the block holds it)"
            )
    return None


def letters(order: Sequence[str], names: Sequence[str] = COLOURS) -> str:
    """An order as `--order` takes it: initials (`BRRBR`), or names with commas.

    Names when two of the option set's names share an initial (blue, black): initials would
    not say which.
    """
    if len({name[0].upper() for name in names}) < len(names):
        return ",".join(order)
    return "".join(o[0].upper() for o in order)


def _check(base: Sequence[str], names: Sequence[str]) -> None:
    if len(names) < 2 or len(set(names)) != len(names):
        raise ValueError(f"an option set is two or more distinct names, got {list(names)}")
    if not base or any(o not in names for o in base):
        raise ValueError(f"a base order is one or more of {'/'.join(names)}, got {list(base)}")
