"""How a bus-driven arm's commands and reports name a box: by colour, or by option index.

The Feetech driver (`feetech_arm.FeetechArm`) and its I/O thread (`threaded_arm.ThreadedArm`)
move over N boxes by index, whatever the table; what differs between the paper's two buzzers
and a table of N boxes is only the words they are spoken to in: the paper's `ArmCommand` and
`ArmState` name red and blue (`PAPER_WORDS`, box 0 red as z > 0 is red), the N-option
`OptionsCommand` and `OptionsArmState` name box indices (`OPTION_WORDS`). One set of words is
given to the driver, so its motion, faults and safe stop are written once for every N.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Generic, Protocol, TypeVar

from services.model.arm import ArmState, OptionsArmState
from services.model.behaviour import ArmCommand, OptionsCommand
from services.model.geometry import COLOURS, Colour, Point


class Command(Protocol):
    """What the driver reads of any arm command: its action (its target through the words)."""

    @property
    def action(self) -> str:
        """idle, stop, move or press."""


class Report(Protocol):
    """What the I/O thread reads of any arm report: its fault."""

    @property
    def fault(self) -> str | None:
        """Why the arm refuses motion, or None when healthy."""


C = TypeVar("C", bound=Command)  # an arm command: `ArmCommand` or `OptionsCommand`
T = TypeVar("T")  # a box as the commands name it: a colour, or an option index
R = TypeVar("R", bound=Report)  # the arm's report: `ArmState` or `OptionsArmState`


class ArmWords(ABC, Generic[C, T, R]):
    """The commands an arm applies and the report it gives, for one way of naming boxes."""

    @abstractmethod
    def target(self, cmd: C) -> T | None:
        """The box a move or press heads for (None for idle and stop)."""

    @abstractmethod
    def box(self, target: T) -> int:
        """The index of a named box (ValueError: none of this table's)."""

    @abstractmethod
    def stop(self, reason: str) -> C:
        """A stop (what a refusal while faulted, and a hold, apply)."""

    @abstractmethod
    def idle(self, reason: str) -> C:
        """No motion asked (the answer to `home`)."""

    @abstractmethod
    def press(self, target: T, reason: str) -> C:
        """A press of `target` (the answer when a press is already committed)."""

    @abstractmethod
    def report(
        self, t: float, ee: Point, moving: bool, target: T | None, pressed: T | None,
        fault: str | None,
    ) -> R:
        """The arm's state at time t (s)."""


class PaperWords(ArmWords[ArmCommand, Colour, ArmState]):
    """The paper's: red and blue, box 0 red."""

    def target(self, cmd: ArmCommand) -> Colour | None:
        """The colour of a move or press."""
        return cmd.target

    def box(self, target: Colour) -> int:
        """Red is box 0, blue box 1."""
        return COLOURS.index(target)

    def stop(self, reason: str) -> ArmCommand:
        """`ArmCommand.stop`."""
        return ArmCommand.stop(reason)

    def idle(self, reason: str) -> ArmCommand:
        """`ArmCommand.idle`."""
        return ArmCommand.idle(reason)

    def press(self, target: Colour, reason: str) -> ArmCommand:
        """`ArmCommand.press`."""
        return ArmCommand.press(target, reason)

    def report(
        self, t: float, ee: Point, moving: bool, target: Colour | None, pressed: Colour | None,
        fault: str | None,
    ) -> ArmState:
        """An `ArmState`."""
        return ArmState(t=t, ee=ee, moving=moving, target=target, pressed=pressed, fault=fault)


class OptionWords(ArmWords[OptionsCommand, int, OptionsArmState]):
    """N boxes by index."""

    def target(self, cmd: OptionsCommand) -> int | None:
        """The box index of a move or press."""
        return cmd.target

    def box(self, target: int) -> int:
        """Boxes are indices already."""
        return target

    def stop(self, reason: str) -> OptionsCommand:
        """A stop."""
        return OptionsCommand("stop", reason=reason)

    def idle(self, reason: str) -> OptionsCommand:
        """An idle."""
        return OptionsCommand("idle", reason=reason)

    def press(self, target: int, reason: str) -> OptionsCommand:
        """A press of box `target`."""
        return OptionsCommand("press", target, reason)

    def report(
        self, t: float, ee: Point, moving: bool, target: int | None, pressed: int | None,
        fault: str | None,
    ) -> OptionsArmState:
        """An `OptionsArmState`."""
        return OptionsArmState(t, ee, moving, target, pressed, fault)


PAPER_WORDS = PaperWords()
OPTION_WORDS = OptionWords()
