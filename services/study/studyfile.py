"""The study file (TOML): a study's name, protocol, conditions and counterbalanced roster.

    [study]
    name = "gaze-consensus"
    params = "params.toml"        # optional: the protocol every session runs (relative path)
    options = ["red", "blue", "green"]  # optional: the option set (default the paper's red, blue)
    on_withdrawal = "keep"        # or "delete" or "aggregate": what `nod study withdraw` does
    consent_version = "v2 2026-03-01"  # optional: the consent form participants sign
    preregistration = "osf.io/abcd3"    # optional: the study's pre-registration id

    [conditions]                  # the protocol's design, checked against `params` at start
    control = [1, 2, 3]           # dissensus trials: neutral gaze, b_r = 0
    consensus = [4, 5, 6, 7, 8]   # consensus trials: the bias toward O, the gaze toward O
    gaze_levels = ["minimal", "low", "moderate", "significant", "extreme"]
    policies = { paper = "paper", adaptive = "adaptive" }  # optional: robot policies between
    assignment = "counterbalanced"  # subjects, one per participant (or "random")

    [counterbalance]
    method = "latin-square"       # or "declared": the orders below, as written
    base = ["blue", "red", "red", "blue", "red"]   # the protocol's own O order
    block = 10                    # participants per balanced block (options x consensus trials)
    seed = 7

    [[participants]]
    id = "P01"
    slot = 1                      # position in the roster: who is next, which order
    order = ["red", "blue", "blue", "red", "blue"] # O of each consensus trial, in order
    condition = "adaptive"        # with policies: the participant's (its session's --policy)

`options` names the boxes of the table, left to right, as the protocol's `[protocol] options`
does (a study of three or more options runs each session with `--options N`, its order by
name); without it the study is the paper's, red and blue, and its file is what it always was.

`nod study init` writes it (`services.model.counterbalance` makes the orders); an operator may
edit ids, and orders with `method = "declared"`. `load` refuses a file whose orders do not fit
its conditions or, for a Latin square, are not its blocks, in one line naming the entry.

`policies` (optional) makes the robot's policy a condition between subjects: each participant
has one, allocated by `nod study init --policies …` from the roster's orders (counterbalanced)
or the seed (random) and stored in their entry (`services.study.conditions`); without it the
file is what it always was.

`on_withdrawal` is what the study's consent form promised a participant who withdraws: "keep"
(the default) keeps their data, left out of every export, analysis and fit; "delete" deletes
it (`services.store.withdrawals.delete_participant`); "aggregate" deletes it too but first adds
their trials' outcomes to the study's anonymous per-trial counts (`withdrawn_aggregates`: no
id, no session, no time). `nod study withdraw --keep/--delete/--aggregate` overrides it for
one person.

`consent_version` and `preregistration` (optional text) go, with the file's SHA-256, its name
and the counterbalance seed, into each session's provenance (`nod study start` gives the
conductor `--study`; `services.core.provenance`).
"""

from __future__ import annotations

import json
import os
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypeAlias, cast

from services.core.provenance import STUDY_TEXT_FIELDS, study_text
from services.model.counterbalance import Names, block_problem, block_size, roster_orders
from services.model.gaze import GAZE_LEVEL_NAMES
from services.model.geometry import COLOURS
from services.model.protocol import TrialSpec, order_of
from services.model.schedule import MAX_OPTIONS, OptionsSchedule, OptionsTrial
from services.store.participants import check_id
from services.study.conditions import (
    KEYS,
    Assignment,
    ConditionsError,
    PolicyConditions,
    allocate,
    check_files,
    counterbalance_problem,
    is_built_in,
    resolve,
)

Method: TypeAlias = Literal["latin-square", "declared"]
METHODS: tuple[Method, Method] = ("latin-square", "declared")
OnWithdrawal: TypeAlias = Literal["keep", "delete", "aggregate"]
ON_WITHDRAWAL: tuple[OnWithdrawal, ...] = ("keep", "delete", "aggregate")
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
    def of(cls, trials: Sequence[TrialSpec] | Sequence[OptionsTrial]) -> Conditions:
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
    base: Names  # the protocol's O order the Latin square rotates and relabels
    seed: int | None  # the shuffle's seed (latin-square)
    options: Names = COLOURS  # the study's option set, whose relabellings balance the block

    @property
    def block(self) -> int:
        """Participants per balanced block."""
        return block_size(len(self.base), len(self.options))


@dataclass(frozen=True, slots=True)
class Entry:
    """One participant of the roster."""

    id: str
    slot: int  # 1-based position in the roster
    order: Names  # O of each consensus trial, by option name
    condition: str | None = None  # the participant's robot-policy condition (`policies`)

    @property
    def letters(self) -> str:
        """The order as initials, `BRRBR` (as `--order` takes it when no two names share one)."""
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
    consent_version: str | None = None  # the consent form's version (provenance)
    preregistration: str | None = None  # the pre-registration's id (provenance)
    policy_conditions: PolicyConditions | None = None  # robot policies, between subjects

    def __post_init__(self) -> None:
        check(self)

    @property
    def options(self) -> Names:
        """The study's option set, in box order (red, blue unless the file names one)."""
        return self.counterbalance.options

    def order_arg(self, entry: Entry) -> str:
        """The entry's order as its session's `--order`: `BRRBR` in the paper's study.

        Over N options by names with commas (`red,green,blue`): never ambiguous, whatever the
        names' initials.
        """
        return entry.letters if self.paper else ",".join(entry.order)

    @property
    def paper(self) -> bool:
        """Whether the study is the paper's two options (its sessions take no `--options`)."""
        return self.options == COLOURS

    def policy_arg(self, entry: Entry) -> str | None:
        """The entry's session's `--policy` (its condition's), or None: a study without them."""
        pc = self.policy_conditions
        return None if pc is None or entry.condition is None else pc.policy(entry.condition)

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
    names = cb.options
    check_options(names)
    one_of = "/".join(names)
    if cb.method not in METHODS:
        raise StudyError(f"[counterbalance] method must be one of {METHODS}, got {cb.method!r}")
    if len(cb.base) != n or any(o not in names for o in cb.base):
        raise StudyError(f"[counterbalance] base needs {one_of} for each of {n} consensus trials")
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
        if len(e.order) != n or any(o not in names for o in e.order):
            raise StudyError(
                f"{where}: order needs {one_of} for each of the {n} consensus trials "
                f"{list(c.consensus)}, got {list(e.order)}"
            )
    if cb.method == "latin-square":
        problem = block_problem(cb.base, [e.order for e in study.participants], names)
        if problem:
            raise StudyError(
                f"{problem}; if the orders were edited on purpose, set [counterbalance] method = "
                '"declared"'
            )
    check_conditions(study)


def check_conditions(study: Study) -> None:
    """StudyError unless every participant has one of the study's policy conditions, as assigned.

    A study without `policies` has no condition anywhere; a latin-square roster's counterbalanced
    conditions are the rule's (`services.study.conditions`), checked by content as its orders are.
    """
    pc, cb = study.policy_conditions, study.counterbalance
    if pc is None:
        if e := next((e for e in study.participants if e.condition is not None), None):
            raise StudyError(f"participant {e.id!r} (slot {e.slot}) has a condition, but "
                             "[conditions] names no policies")
        return
    try:
        pc.check()
    except ConditionsError as exc:
        raise StudyError(str(exc)) from None
    if not study.paper:
        raise StudyError("[conditions] policies: a robot policy runs on the paper's two-option "
                         "table only")
    if pc.assignment == "random" and cb.seed is None:
        raise StudyError('[conditions] assignment = "random" needs [counterbalance] seed')
    for e in study.participants:
        if e.condition not in pc.names:
            got = "none" if e.condition is None else repr(e.condition)
            raise StudyError(f"participant {e.id!r} (slot {e.slot}): condition must be one of "
                             f"{list(pc.names)}, got {got}")
    if cb.method == "latin-square" and pc.assignment == "counterbalanced":
        problem = counterbalance_problem(
            pc, cb.base, [(e.id, e.order, e.condition or "") for e in study.participants],
            cb.options)
        if problem:
            raise StudyError(f"{problem}; if the conditions were edited on purpose, set "
                             '[counterbalance] method = "declared"')


def check_options(names: Sequence[str]) -> None:
    """StudyError unless `names` is an option set a study can run: the paper's, or 3 to 8."""
    if len(set(names)) != len(names) or not 2 <= len(names) <= MAX_OPTIONS or not all(names):
        raise StudyError(
            f"[study] options must be 2 to {MAX_OPTIONS} distinct names, got {list(names)}"
        )
    if len(names) == 2 and tuple(names) != COLOURS:
        raise StudyError(
            f"[study] options {list(names)}: two options are the paper's study, red and blue "
            "(leave options out); name three or more for a table of N boxes"
        )


def make_study(
    name: str,
    trials: Sequence[TrialSpec] | OptionsSchedule,
    participants: int,
    seed: int,
    params: Path | None = None,
    prefix: str = "P",
    policies: PolicyConditions | None = None,
) -> Study:
    """A new study: ids `<prefix>01…`, slots 1..N, orders from the Latin square of the schedule.

    `trials`: the paper's trials (its option set red, blue) or a schedule of N options, whose
    names become the study's option set. `policies`: robot-policy conditions, one allocated to
    each participant (`services.study.conditions.allocate`).
    """
    if not 1 <= participants <= MAX_PARTICIPANTS:
        raise StudyError(f"--participants must be in 1..{MAX_PARTICIPANTS}, got {participants}")
    names, base = protocol_order(trials)
    if not base:
        raise StudyError("the protocol has no consensus trial: nothing to counterbalance")
    width = max(2, len(str(participants)))
    orders = roster_orders(base, participants, seed, names)
    picks: list[str | None] = [None] * len(orders)
    if policies is not None:
        try:
            policies.check()
            picks = list(allocate(policies, base, orders, names, seed))
        except ConditionsError as exc:
            raise StudyError(str(exc)) from None
    entries = tuple(
        Entry(f"{prefix}{k:0{width}d}", k, order, pick)
        for k, (order, pick) in enumerate(zip(orders, picks, strict=True), start=1)
    )
    return Study(
        name,
        params,
        Conditions.of(trials.trials if isinstance(trials, OptionsSchedule) else trials),
        Counterbalance("latin-square", base, seed, names),
        entries,
        policy_conditions=policies,
    )


def protocol_order(trials: Sequence[TrialSpec] | OptionsSchedule) -> tuple[Names, Names]:
    """The option set and the O order (by name) of a protocol: the paper's trials or N options'."""
    if not isinstance(trials, OptionsSchedule):
        return COLOURS, order_of(trials)
    names = trials.names
    return names, tuple(names[t.option] for t in trials.trials
                        if t.mode == "consensus" and t.option is not None)


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
    if unknown := sorted(set(cond) - {"control", "consensus", "gaze_levels", *KEYS}):
        raise StudyError(f"[conditions] has unknown key(s) {unknown}: it takes control, "
                         "consensus, gaze_levels, policies and assignment")
    policies = _policies(cond, folder)
    cb = _table(data, "counterbalance")
    params = study.get("params")
    if params is not None and not isinstance(params, str):
        raise StudyError("[study] params must be a path (a string)")
    names = COLOURS if "options" not in study else tuple(
        _strings(study["options"], "[study] options"))
    check_options(names)  # before the orders are read as names of it
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
        condition = row.get("condition")
        if condition is not None and not isinstance(condition, str):
            raise StudyError(f"{ident}'s condition must be a string")
        entries.append(Entry(ident, slot, _names(row.get("order"), f"{ident}'s order", names),
                             condition))
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
            _names(cb.get("base"), "[counterbalance] base", names),
            seed,
            names,
        ),
        participants=tuple(entries),
        on_withdrawal=cast(OnWithdrawal, study.get("on_withdrawal", "keep")),
        consent_version=_text(study, "consent_version"),
        preregistration=_text(study, "preregistration"),
        policy_conditions=policies,
    )
    if block is not None and block != out.counterbalance.block:
        raise StudyError(
            f"[counterbalance] block = {block}, but {len(out.counterbalance.base)} consensus "
            f"trials make blocks of {out.counterbalance.block}"
            + ("" if names == COLOURS else f" over {len(names)} options")
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
    if not study.paper:  # the paper's study file stays as it always was
        lines.append(f"options = {_list(study.options)}  # the table's boxes, left to right")
    lines.append(f"on_withdrawal = {_q(study.on_withdrawal)}  # keep, delete or aggregate a "
                 "withdrawn participant's data")
    for key in STUDY_TEXT_FIELDS:
        if (value := getattr(study, key)) is not None:
            lines.append(f"{key} = {_q(value)}")
    lines += [
        "",
        "[conditions]",
        f"control = {_list(c.control)}  # dissensus: neutral gaze, b_r = 0",
        f"consensus = {_list(c.consensus)}  # the bias toward O, the gaze toward O",
        f"gaze_levels = {_list(c.gaze_levels)}",
    ]
    if (pc := study.policy_conditions) is not None:
        listed = ", ".join(f"{name} = {_q(_policy_text(value, path))}"
                           for name, value in pc.policies)
        lines += ["# robot policies between subjects, one per participant: condition = --policy",
                  f"policies = {{ {listed} }}",
                  f"assignment = {_q(pc.assignment)}  # or random (seeded by the seed below)"
                  if pc.assignment == "counterbalanced" else
                  f"assignment = {_q(pc.assignment)}  # seeded by the seed below"]
    lines += [
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
        if e.condition is not None:
            lines.append(f"condition = {_q(e.condition)}")
    return "\n".join(lines) + "\n"


def write(study: Study, path: Path) -> None:
    """Write the study file (atomically: a half-written roster is never left behind)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(dump(study, path), encoding="utf-8")
    tmp.replace(path)


def _policy_text(value: str, path: Path) -> str:
    """A condition's policy as the file at `path` gives it: a file relative to it."""
    if is_built_in(value):
        return value
    return Path(os.path.relpath(Path(value).resolve(), path.resolve().parent)).as_posix()


def _policies(cond: dict[str, Any], folder: Path) -> PolicyConditions | None:
    """[conditions] policies and assignment, the files' paths absolute; None: not given."""
    raw, assignment = cond.get("policies"), cond.get("assignment", "counterbalanced")
    if raw is None:
        if "assignment" in cond:
            raise StudyError("[conditions] assignment without policies: name the conditions "
                             '(policies = { paper = "paper", adaptive = "adaptive" })')
        return None
    if not isinstance(raw, dict) or not all(isinstance(v, str) for v in raw.values()):
        raise StudyError("[conditions] policies must be a table of condition = policy (paper, "
                         "adaptive or a policy file's path), e.g. { paper = \"paper\" }")
    if not isinstance(assignment, str):
        raise StudyError("[conditions] assignment must be a string")
    pc = PolicyConditions(tuple((name, resolve(value, folder) if value.strip() else value)
                                for name, value in raw.items()), cast(Assignment, assignment))
    try:
        pc.check()
        check_files(pc)  # before the participants' conditions are read as names of it
    except ConditionsError as exc:
        raise StudyError(str(exc)) from None
    return pc


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


def _text(table: dict[str, Any], key: str) -> str | None:
    """An optional [study] text (consent_version, preregistration): StudyError if malformed."""
    try:
        return study_text(table, key)
    except ValueError as exc:
        raise StudyError(str(exc)) from None


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


def _names(value: object, where: str, names: Sequence[str]) -> Names:
    items = _strings(value, where)
    if any(v not in names for v in items):
        listed = " or ".join(names) if len(names) == 2 else f"one of {list(names)} each time"
        raise StudyError(f"{where} must list {listed}, got {items}")
    return tuple(items)
