"""The study file (TOML): a study's name, protocol, conditions and counterbalanced roster.

    [study]
    name = "gaze-consensus"
    params = "params.toml"        # optional: the protocol every session runs (relative path)
    on_withdrawal = "keep"        # or "delete": what `nod study withdraw` does with their data

    [conditions]                  # the protocol's design, checked against `params` at start
    control = [1, 2, 3]           # dissensus trials: neutral gaze, b_r = 0
    consensus = [4, 5, 6, 7, 8]   # consensus trials: the bias toward O, the gaze toward O
    gaze_levels = ["minimal", "low", "moderate", "significant", "extreme"]

    [counterbalance]
    method = "latin-square"       # or "declared": the orders below, as written
    base = ["blue", "red", "red", "blue", "red"]   # the protocol's own O order
    block = 10                    # participants per balanced block (2 x consensus trials)
    seed = 7

    [[participants]]
    id = "P01"
    slot = 1                      # position in the roster: who is next, which order
    order = ["red", "blue", "blue", "red", "blue"] # O of each consensus trial, in order

`nod study init` writes it (`services.model.counterbalance` makes the orders); an operator may
edit ids, and orders with `method = "declared"`. `load` refuses a file whose orders do not fit
its conditions or, for a Latin square, are not its blocks, in one line naming the entry.

`on_withdrawal` is what the study's consent form promised a participant who withdraws: "keep"
(the default) keeps their data, left out of every export, analysis and fit; "delete" deletes
it (`services.store.withdrawals.delete_participant`). `nod study withdraw --keep/--delete`
overrides it for one person.
"""

from __future__ import annotations

import json
import os
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypeAlias, cast

from services.model.counterbalance import block_problem, block_size, roster_orders
from services.model.gaze import GAZE_LEVEL_NAMES
from services.model.protocol import Order, TrialSpec, order_of
from services.store.participants import check_id

Method: TypeAlias = Literal["latin-square", "declared"]
METHODS: tuple[Method, Method] = ("latin-square", "declared")
OnWithdrawal: TypeAlias = Literal["keep", "delete"]
ON_WITHDRAWAL: tuple[OnWithdrawal, OnWithdrawal] = ("keep", "delete")
MAX_PARTICIPANTS = 10_000


class StudyError(ValueError):
    """A study file cannot be read or does not hold together; the message says where."""


@dataclass(frozen=True, slots=True)
class Conditions:
    """The protocol's design: which trials are control, which consensus, and their gaze levels."""

    control: tuple[int, ...]  # dissensus trials (neutral gaze, b_r = 0)
    consensus: tuple[int, ...]  # consensus trials, in order
    gaze_levels: tuple[str, ...]  # the gaze level of each consensus trial (fixed by position)

    @classmethod
    def of(cls, trials: Sequence[TrialSpec]) -> Conditions:
        """The conditions of a schedule."""
        consensus = [t for t in trials if t.mode == "consensus"]
        return cls(
            tuple(t.index for t in trials if t.mode == "dissensus"),
            tuple(t.index for t in consensus),
            tuple(t.gaze_level for t in consensus),
        )

    def describe(self) -> str:
        """One line: `control 1-3, consensus 4-8 (minimal, …, extreme)`."""
        return f"control {_span(self.control)}, consensus {_span(self.consensus)} " + (
            f"({', '.join(self.gaze_levels)})"
        )


@dataclass(frozen=True, slots=True)
class Counterbalance:
    """How the orders were made."""

    method: Method
    base: Order  # the protocol's O order the Latin square rotates and reverses
    seed: int | None  # the shuffle's seed (latin-square)

    @property
    def block(self) -> int:
        """Participants per balanced block."""
        return block_size(len(self.base))


@dataclass(frozen=True, slots=True)
class Entry:
    """One participant of the roster."""

    id: str
    slot: int  # 1-based position in the roster
    order: Order  # O of each consensus trial

    @property
    def letters(self) -> str:
        """The order as letters, `BRRBR`, as `--order` takes it."""
        return "".join(o[0].upper() for o in self.order)


@dataclass(frozen=True, slots=True)
class Study:
    """A study file's content; the entries sorted by slot (1..N)."""

    name: str
    params: Path | None  # the protocol's parameters file (absolute), or None for SPEC defaults
    conditions: Conditions
    counterbalance: Counterbalance
    participants: tuple[Entry, ...]
    on_withdrawal: OnWithdrawal = "keep"  # what a withdrawal does with their data

    def __post_init__(self) -> None:
        check(self)

    def entry(self, participant: str) -> Entry | None:
        """The participant's entry, or None if they are not in the study."""
        return next((e for e in self.participants if e.id == participant), None)


def check(study: Study) -> None:
    """StudyError naming the first thing that does not hold together."""
    c = study.conditions
    if not study.name.strip():
        raise StudyError("[study] name is empty")
    if study.on_withdrawal not in ON_WITHDRAWAL:
        raise StudyError(
            f"[study] on_withdrawal must be one of {ON_WITHDRAWAL}, got {study.on_withdrawal!r}"
        )
    if sorted(c.control + c.consensus) != list(range(1, len(c.control) + len(c.consensus) + 1)):
        raise StudyError(
            f"[conditions] control {list(c.control)} and consensus {list(c.consensus)} must "
            "number the trials 1..n once each"
        )
    if not c.consensus:
        raise StudyError("[conditions] consensus is empty: nothing to counterbalance")
    if len(c.gaze_levels) != len(c.consensus) or any(
        g not in GAZE_LEVEL_NAMES for g in c.gaze_levels
    ):
        raise StudyError(
            f"[conditions] gaze_levels needs one of {GAZE_LEVEL_NAMES} per consensus trial, got "
            f"{list(c.gaze_levels)}"
        )
    n = len(c.consensus)
    cb = study.counterbalance
    if cb.method not in METHODS:
        raise StudyError(f"[counterbalance] method must be one of {METHODS}, got {cb.method!r}")
    if len(cb.base) != n or any(o not in ("red", "blue") for o in cb.base):
        raise StudyError(f"[counterbalance] base needs red/blue for each of {n} consensus trials")
    if not 1 <= len(study.participants) <= MAX_PARTICIPANTS:
        raise StudyError(f"a study has 1 to {MAX_PARTICIPANTS} participants")
    seen: set[str] = set()
    for i, e in enumerate(study.participants, start=1):
        where = f"participant {e.id!r} (slot {e.slot})"
        try:
            check_id(e.id)
        except ValueError as exc:
            raise StudyError(f"{where}: {exc}") from None
        if e.id in seen:
            raise StudyError(f"{where}: the id is given twice")
        seen.add(e.id)
        if e.slot != i:
            raise StudyError(f"slots must be 1..{len(study.participants)} once each; {where}")
        if len(e.order) != n or any(o not in ("red", "blue") for o in e.order):
            raise StudyError(
                f"{where}: order needs red/blue for each of the {n} consensus trials "
                f"{list(c.consensus)}, got {list(e.order)}"
            )
    if cb.method == "latin-square":
        problem = block_problem(cb.base, [e.order for e in study.participants])
        if problem:
            raise StudyError(
                f"{problem}; if the orders were edited on purpose, set [counterbalance] method = "
                '"declared"'
            )


def make_study(
    name: str,
    trials: Sequence[TrialSpec],
    participants: int,
    seed: int,
    params: Path | None = None,
    prefix: str = "P",
) -> Study:
    """A new study: ids `<prefix>01…`, slots 1..N, orders from the Latin square of the schedule."""
    if not 1 <= participants <= MAX_PARTICIPANTS:
        raise StudyError(f"--participants must be in 1..{MAX_PARTICIPANTS}, got {participants}")
    base = order_of(trials)
    if not base:
        raise StudyError("the protocol has no consensus trial: nothing to counterbalance")
    width = max(2, len(str(participants)))
    orders = roster_orders(base, participants, seed)
    entries = tuple(
        Entry(f"{prefix}{k:0{width}d}", k, order) for k, order in enumerate(orders, start=1)
    )
    return Study(
        name,
        params,
        Conditions.of(trials),
        Counterbalance("latin-square", base, seed),
        entries,
    )


def load(path: Path) -> Study:
    """Read and check a study file; StudyError says what is wrong where."""
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise StudyError(f"no study file {path}: make one with `nod study init {path}`") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise StudyError(f"{path} is not a readable TOML study file: {exc}") from None
    try:
        return _from_mapping(data, path.parent)
    except StudyError as exc:
        raise StudyError(f"{path}: {exc}") from None


def _from_mapping(data: dict[str, Any], folder: Path) -> Study:
    study = _table(data, "study")
    cond = _table(data, "conditions")
    cb = _table(data, "counterbalance")
    params = study.get("params")
    if params is not None and not isinstance(params, str):
        raise StudyError("[study] params must be a path (a string)")
    seed = cb.get("seed")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
        raise StudyError("[counterbalance] seed must be an integer")
    rows = data.get("participants")
    if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
        raise StudyError("the file needs [[participants]] entries (id, slot, order)")
    entries = []
    for row in rows:
        ident, slot = row.get("id"), row.get("slot")
        if not isinstance(ident, str) or isinstance(slot, bool) or not isinstance(slot, int):
            raise StudyError(
                f"a [[participants]] entry needs id (a string) and slot (an integer): {row}"
            )
        entries.append(Entry(ident, slot, _colours(row.get("order"), f"{ident}'s order")))
    entries.sort(key=lambda e: e.slot)
    block = cb.get("block")
    out = Study(
        name=_string(study, "name", "[study]"),
        params=None if params is None else (folder / params).resolve(),
        conditions=Conditions(
            _ints(cond.get("control"), "[conditions] control"),
            _ints(cond.get("consensus"), "[conditions] consensus"),
            tuple(_strings(cond.get("gaze_levels"), "[conditions] gaze_levels")),
        ),
        counterbalance=Counterbalance(
            cast(Method, _string(cb, "method", "[counterbalance]")),
            _colours(cb.get("base"), "[counterbalance] base"),
            seed,
        ),
        participants=tuple(entries),
        on_withdrawal=cast(OnWithdrawal, study.get("on_withdrawal", "keep")),
    )
    if block is not None and block != out.counterbalance.block:
        raise StudyError(
            f"[counterbalance] block = {block}, but {len(out.counterbalance.base)} consensus "
            f"trials make blocks of {out.counterbalance.block}"
        )
    return out


def dump(study: Study, path: Path) -> str:
    """The study file's text, with `params` relative to where it is written (`path`)."""
    c, cb = study.conditions, study.counterbalance
    lines = [
        f"# A study file: `nod study status {path.name}` shows who is done and who is next.",
        "# Trials and gaze levels are the protocol's; the O order of the consensus trials is",
        "# counterbalanced per participant, and the eyes always look toward O (docs/study.md).",
        "[study]",
        f"name = {_q(study.name)}",
    ]
    if study.params is not None:
        rel = os.path.relpath(study.params.resolve(), path.resolve().parent)
        lines.append(f"params = {_q(Path(rel).as_posix())}")
    lines.append(f"on_withdrawal = {_q(study.on_withdrawal)}  # keep or delete a withdrawn "
                 "participant's data")
    lines += [
        "",
        "[conditions]",
        f"control = {_list(c.control)}  # dissensus: neutral gaze, b_r = 0",
        f"consensus = {_list(c.consensus)}  # the bias toward O, the gaze toward O",
        f"gaze_levels = {_list(c.gaze_levels)}",
        "",
        "[counterbalance]",
        f"method = {_q(cb.method)}",
        f"base = {_list(cb.base)}",
        f"block = {cb.block}",
    ]
    if cb.seed is not None:
        lines.append(f"seed = {cb.seed}")
    for e in study.participants:
        lines += ["", "[[participants]]", f"id = {_q(e.id)}", f"slot = {e.slot}",
                  f"order = {_list(e.order)}"]
    return "\n".join(lines) + "\n"


def write(study: Study, path: Path) -> None:
    """Write the study file (atomically: a half-written roster is never left behind)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(dump(study, path), encoding="utf-8")
    tmp.replace(path)


def _span(indices: Sequence[int]) -> str:
    if not indices:
        return "none"
    if list(indices) == list(range(indices[0], indices[-1] + 1)):
        return f"{indices[0]}-{indices[-1]}" if len(indices) > 1 else str(indices[0])
    return ",".join(map(str, indices))


def _q(text: str) -> str:
    return json.dumps(text, ensure_ascii=False)  # a TOML basic string


def _list(items: Sequence[object]) -> str:
    return "[" + ", ".join(_q(i) if isinstance(i, str) else str(i) for i in items) + "]"


def _table(data: dict[str, Any], name: str) -> dict[str, Any]:
    table = data.get(name)
    if not isinstance(table, dict):
        raise StudyError(f"the file needs a [{name}] table")
    return table


def _string(table: dict[str, Any], key: str, where: str) -> str:
    value = table.get(key)
    if not isinstance(value, str):
        raise StudyError(f"{where} {key} must be a string")
    return value


def _ints(value: object, where: str) -> tuple[int, ...]:
    if not isinstance(value, list) or any(isinstance(v, bool) or not isinstance(v, int)
                                          for v in value):
        raise StudyError(f"{where} must be a list of trial numbers")
    return tuple(value)


def _strings(value: object, where: str) -> list[str]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise StudyError(f"{where} must be a list of strings")
    return list(value)


def _colours(value: object, where: str) -> Order:
    items = _strings(value, where)
    if any(v not in ("red", "blue") for v in items):
        raise StudyError(f"{where} must list red or blue, got {items}")
    return cast(Order, tuple(items))
