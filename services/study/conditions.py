"""A study's robot policies as conditions between subjects: one per participant (issue 36).

    [conditions]
    control = [1, 2, 3]                # the protocol's design, as before
    consensus = [4, 5, 6, 7, 8]
    gaze_levels = ["minimal", "low", "moderate", "significant", "extreme"]
    policies = { paper = "paper", adaptive = "adaptive" }  # condition -> its --policy
    assignment = "counterbalanced"     # or "random"

    [[participants]]
    id = "P01"
    slot = 1
    order = ["red", "blue", "blue", "red", "blue"]
    condition = "adaptive"             # the participant's condition: its session's --policy

A condition's policy is a built-in's name (`paper`, `adaptive`) or a policy file's path,
relative to the study file (`services.cohort.policy_file`). `nod study init --policies …` writes
each participant's condition into the file beside their order, so a resumed or restarted
participant keeps theirs and the roster never depends on being regenerated.

**counterbalanced**: with K conditions (in the order `policies` lists them) and the orders'
Latin-square blocks of B = n·N_o slots (`services.model.counterbalance`), the participant in
block b (slots b·B + 1 … (b + 1)·B) whose order is row i of the square (`latin_block`) gets
condition (i + b) mod K. So over any K consecutive blocks each condition meets every order of
the square exactly once (within each condition the orders are a full Latin-square block: every
option O equally often at every trial, the carry-over balanced), each block splits as evenly as
it can (B/K each), and when K divides N_o (the paper's study and two conditions) each group of
a rotation and its relabellings, which the roster keeps adjacent, holds every condition: after
every N_o participants the conditions are balanced. It is checked by content at load, as the
orders are; a file whose conditions were edited on purpose declares its orders (`method =
"declared"`), and its conditions are then taken as written too.

**random**: each participant's condition drawn independently and uniformly, seeded by the
study's allocation seed (`[counterbalance] seed`): simple randomisation, whose group sizes vary.
"""

from __future__ import annotations

import random
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, TypeAlias

from services.model.counterbalance import Names, block_size, latin_block

Assignment: TypeAlias = Literal["counterbalanced", "random"]
ASSIGNMENTS: tuple[Assignment, ...] = ("counterbalanced", "random")
NAME = re.compile(r"[A-Za-z0-9_-]{1,32}")  # a condition's name (a bare TOML key)
KEYS = ("policies", "assignment")  # the [conditions] keys of this module


class ConditionsError(ValueError):
    """The study's policy conditions do not hold together; the message says where."""


@dataclass(frozen=True, slots=True)
class PolicyConditions:
    """The study's conditions between subjects: each a robot policy, and how they are assigned."""

    policies: tuple[tuple[str, str], ...]  # (condition, --policy: a built-in or a file's path)
    assignment: Assignment = "counterbalanced"

    @property
    def names(self) -> tuple[str, ...]:
        """The conditions, in the order the file lists them."""
        return tuple(name for name, _ in self.policies)

    def policy(self, condition: str) -> str:
        """The condition's `--policy` value."""
        return dict(self.policies)[condition]

    def check(self) -> None:
        """ConditionsError naming what does not hold together (files are `check_files`')."""
        if not self.policies:
            raise ConditionsError("[conditions] policies is empty: name one condition or more")
        for name, value in self.policies:
            if not NAME.fullmatch(name):
                raise ConditionsError(
                    f"[conditions] policies: condition {name!r} must be 1-32 letters, digits, "
                    "_ or -")
            if not value.strip():
                raise ConditionsError(f"[conditions] policies.{name} is empty")
        if len(set(self.names)) != len(self.names):
            raise ConditionsError("[conditions] policies names a condition twice")
        if self.assignment not in ASSIGNMENTS:
            raise ConditionsError(f"[conditions] assignment must be one of {ASSIGNMENTS}, got "
                                  f"{self.assignment!r}")


def is_built_in(value: str) -> bool:
    """Whether `value` names a built-in policy (`paper`, `adaptive`), not a file."""
    from services.cohort.policy_file import BUILT_IN

    return value in BUILT_IN


def resolve(value: str, folder: Path) -> str:
    """A policy as the study file gives it: a built-in's name as is, a file's path absolute."""
    return value if is_built_in(value) else str((folder / value).resolve())


def check_files(pc: PolicyConditions) -> None:
    """ConditionsError unless each condition's policy is a built-in or a policy file that reads."""
    from services.cohort.policy_file import BUILT_IN, read_policy_file

    for name, value in pc.policies:
        if value in BUILT_IN:
            continue
        if not Path(value).is_file():
            raise ConditionsError(
                f"[conditions] policies.{name}: no policy file {value} (a path relative to the "
                f"study file, or a built-in: {', '.join(BUILT_IN)})")
        try:
            read_policy_file(value)
        except ValueError as exc:
            raise ConditionsError(f"[conditions] policies.{name}: {exc}") from None


def identity(value: str) -> tuple[str, str]:
    """(name, SHA-256) of a policy, as a session running it stores them (policy_sessions)."""
    from services.cohort.policy_file import read_policy_file

    pf = read_policy_file(value)
    return pf.name, pf.sha256


def counterbalanced(
    base: Sequence[str], orders: Sequence[Sequence[str]], names: Sequence[str], k: int
) -> list[int]:
    """The condition (index) of slots 1..N by their orders: (row + block) mod k (module doc).

    `orders` must be rows of the Latin square of `base` (a latin-square roster). A base whose
    rotations repeat (RBRB) has an order on several rows: its m-th occurrence in a block is its
    m-th row.
    """
    rows: dict[Names, list[int]] = {}
    for i, order in enumerate(latin_block(base, names)):
        rows.setdefault(order, []).append(i)
    size = block_size(len(base), len(names))
    out = []
    for start in range(0, len(orders), size):
        left = {order: list(at) for order, at in rows.items()}
        out += [(left[tuple(o)].pop(0) + start // size) % k for o in orders[start:start + size]]
    return out


def randomised(participants: int, k: int, seed: int) -> list[int]:
    """The condition (index) of slots 1..N, drawn uniformly and independently from `seed`."""
    rng = random.Random(f"nod-study-conditions:{seed}")  # its own stream, not the orders'
    return [rng.randrange(k) for _ in range(participants)]


def allocate(
    pc: PolicyConditions, base: Sequence[str], orders: Sequence[Sequence[str]],
    names: Sequence[str], seed: int | None,
) -> list[str]:
    """Each slot's condition by name: counterbalanced over the roster's orders, or seeded."""
    k = len(pc.policies)
    if pc.assignment == "counterbalanced":
        picks = counterbalanced(base, orders, names, k)
    else:
        if seed is None:
            raise ConditionsError('assignment = "random" needs [counterbalance] seed')
        picks = randomised(len(orders), k, seed)
    return [pc.names[i] for i in picks]


def counterbalance_problem(
    pc: PolicyConditions, base: Sequence[str], slots: Sequence[tuple[str, Sequence[str], str]],
    names: Sequence[str],
) -> str | None:
    """Why the conditions of a latin-square roster are not the counterbalanced ones, or None.

    `slots`: (id, order, condition) of slots 1..N, their orders already checked to be the
    square's.
    """
    want = allocate(pc, base, [o for _, o, _ in slots], names, None)
    for slot, ((ident, _, have), expected) in enumerate(zip(slots, want, strict=True), start=1):
        if have != expected:
            return (f"participant {ident!r} (slot {slot}): condition {have!r}, but the "
                    f"counterbalanced allocation gives {expected!r}")
    return None
