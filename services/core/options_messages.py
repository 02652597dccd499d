"""The N_o-option messages: vectors over the options, on topics of their own, schema version 2.

A table of three or more boxes talks on `options/*` keys (`services.core.contract`) with these
messages, which carry one value per option. They are schema version 2 (`v` = 2): a payload of
version 1 — the paper's messages, or a service of before the option set — is refused with
"schema version is not 2", and one of version 2 on a paper key with "… is not 1". The paper's
two-option topics and messages are unchanged, byte for byte, so the study's recordings,
replays and stores are too (docs/multi-option.md says why this is not one message type for
both).

Every vector's length is checked twice: against the message's own `n_options` when it has one
(a message that disagrees with itself never decodes), and against the receiver's option count
by `values_for` (a service started with another `--options` is refused with one line).
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal, TypeAlias, TypedDict

import msgspec
import numpy as np

from services.core.messages import (
    Box4,
    Counter,
    Message,
    MessageError,
    Mode,
    Opinion,
    Score,
    Table,
    Text,
    Trial,
    TrialPhase,
    Unit,
)
from services.model.geometry import Box, CommitLine, OptionsLayout
from services.model.schedule import MAX_OPTIONS

OPTIONS_SCHEMA_VERSION = 2
OptionCount: TypeAlias = Annotated[int, msgspec.Meta(ge=2, le=MAX_OPTIONS)]
OptionIndex: TypeAlias = Annotated[int, msgspec.Meta(ge=0, le=MAX_OPTIONS - 1)]
Vector: TypeAlias = Annotated[
    tuple[Opinion, ...], msgspec.Meta(min_length=2, max_length=MAX_OPTIONS)
]
OptionName: TypeAlias = Annotated[str, msgspec.Meta(min_length=1, max_length=32)]


class OptionsMessage(
    Message, frozen=True, kw_only=True, tag=OPTIONS_SCHEMA_VERSION
):
    """Base of the N_o-option messages: `v` = 2, `seq`, `t_ns`."""

    KIND: ClassVar[str] = "options"


class OptionVector(OptionsMessage, frozen=True, kw_only=True):
    """One quantity over the options (ẑ_h, z_r or b_r) computed from hand pose `src_seq`."""

    KIND: ClassVar[str] = "option_vector"
    values: Vector = (0.0, 0.0)
    src_seq: Counter = 0


def values_for(msg: OptionVector, n_options: int) -> np.ndarray:
    """The vector as an array, refused with one line when its length is not `n_options`."""
    if len(msg.values) != n_options:
        raise MessageError(
            f"{msg.KIND}: {len(msg.values)} values but this rig runs {n_options} options; "
            "start every service with the same --options (or params file)"
        )
    return np.array(msg.values, dtype=float)


def check_count(msg: _WithOptionCount, n_options: int) -> None:
    """Refuse (MessageError, one line) a message for another number of options than ours."""
    if msg.n_options != n_options:
        raise MessageError(
            f"{msg.KIND}: for {msg.n_options} options but this rig runs {n_options}; start "
            "every service with the same --options (or params file)"
        )


def same_count(layout: OptionsLayout, n_options: int) -> OptionsLayout:
    """The layout, refused (MessageError, one line) when it has another number of boxes."""
    if layout.n_options != n_options:
        raise MessageError(
            f"options_layout: {layout.n_options} boxes but this rig runs {n_options} options; "
            "start every service with the same --options (or params file)"
        )
    return layout


class OptionsLayoutMsg(OptionsMessage, frozen=True, kw_only=True):
    """The table: option names, one box [x1, y1, x2, y2] per option, the commit line y."""

    KIND: ClassVar[str] = "options_layout"
    names: Annotated[tuple[OptionName, ...], msgspec.Meta(min_length=2, max_length=MAX_OPTIONS)]
    boxes: Annotated[tuple[Box4, ...], msgspec.Meta(min_length=2, max_length=MAX_OPTIONS)]
    commit_y: Unit = 0.45

    def __post_init__(self) -> None:
        if len(self.names) != len(self.boxes):
            raise MessageError(
                f"options_layout: {len(self.names)} names but {len(self.boxes)} boxes"
            )
        for j, (x1, y1, x2, y2) in enumerate(self.boxes):
            if x1 > x2 or y1 > y2:
                raise MessageError(f"options_layout: box {j} needs x1 <= x2 and y1 <= y2")

    def layout(self) -> OptionsLayout:
        """The geometry it carries."""
        return OptionsLayout(tuple(Box(*b) for b in self.boxes), CommitLine(y=self.commit_y))


class LayoutFields(TypedDict):
    """The fields of an `options/layout` message."""

    names: tuple[str, ...]
    boxes: tuple[tuple[float, float, float, float], ...]
    commit_y: float


def layout_message_fields(names: tuple[str, ...], layout: OptionsLayout) -> LayoutFields:
    """The fields of an `options/layout` message for a geometry and its option names."""
    return {
        "names": names,
        "boxes": tuple((b.x1, b.y1, b.x2, b.y2) for b in layout.boxes),
        "commit_y": layout.commit.y,
    }


class _WithOptionCount(OptionsMessage, frozen=True, kw_only=True):
    """A message naming options by index, with the count they index into."""

    n_options: OptionCount = 3

    def _check(self, **options: int | None) -> None:
        for name, value in options.items():
            if value is not None and value >= self.n_options:
                raise MessageError(
                    f"{self.KIND}: {name} {value} is not one of the {self.n_options} options"
                )


class OptionsArmState(_WithOptionCount, frozen=True, kw_only=True):
    """The N_o-box arm's state: end effector, phase, the box it heads for, safety."""

    KIND: ClassVar[str] = "options_arm_state"
    ee: tuple[Table, Table] = (0.5, 0.1)
    phase: Text = "idle"
    moving: bool = False
    target: OptionIndex | None = None
    safe_stop: bool = False
    safety_reason: Text = ""
    trial: Trial = 0

    def __post_init__(self) -> None:
        self._check(target=self.target)


class OptionsPress(_WithOptionCount, frozen=True, kw_only=True):
    """The robot's press of box `option` in trial `trial`."""

    KIND: ClassVar[str] = "options_press"
    option: OptionIndex = 0
    trial: Trial = 0

    def __post_init__(self) -> None:
        self._check(option=self.option)


class OptionsTrialEvent(_WithOptionCount, frozen=True, kw_only=True):
    """A step of the protocol over N_o options (`messages.TrialEvent` with O an index)."""

    KIND: ClassVar[str] = "options_trial"
    phase: TrialPhase = "setup"
    trial: Trial = 0
    mode: Mode = "dissensus"
    option: OptionIndex | None = None
    text: Text = ""
    session: Text = ""

    def __post_init__(self) -> None:
        self._check(option=self.option)


class OptionsResult(_WithOptionCount, frozen=True, kw_only=True):
    """The classified outcome of one N_o-option trial (options as indices)."""

    KIND: ClassVar[str] = "options_result"
    trial: Trial = 0
    mode: Mode = "dissensus"
    option: OptionIndex | None = None
    robot: OptionIndex | None = None
    human: OptionIndex | None = None
    outcome: Literal["C", "CH", "D", "DH"] | None = None
    switches: Trial = 0
    violations: Trial = 0
    score: Score = 0
    session: Text = ""
    interrupted: bool = False  # broken by safe stops and not repeated: stored, never scored

    def __post_init__(self) -> None:
        self._check(option=self.option, robot=self.robot, human=self.human)
