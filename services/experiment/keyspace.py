"""The one seam between the conductor and its number of options: the session's form.

`services.experiment.conductor.Conductor` is written once for any option set, on one key space
(schema 3: `experiment/trial`, `experiment/result`, `decision/z_h|z_r|b_r`, `actuation/state`,
`actuation/press`, `vision/layout`; each message carries or names its options, and each one
heard is checked against the session's option set). What a session does differently by its
number of options lives here, chosen by the option count (`key_space`):

- `PaperKeys`, the paper's study (two options, red and blue): its trials are the `TrialSpec`s
  of the configuration, which carry mode and O; the judge is `TrialJudge` (the two-option
  kernel: O a colour, ẑ_h the signed number of the vector (z, -z)).
- `OptionKeys`, a table of three or more boxes: the clock runs `OptionsSchedule.timing_specs`
  and each trial's mode and O are the schedule's; the judge is `OptionsTrialJudge` (O a box
  index, ẑ_h a vector).

The conductor speaks in option *names* (what the messages carry, the store keeps, the console
shows, the analysis reads); a session's form turns a box of its judge into a name (`name`) and
a name heard on the wire into its judge's box (`box`). Readings come to the conductor in
neutral form (`Output`, `ArmReading`, a press's trial and box), so the gate, the cues as
played, the samples, the recorder, resume, the rig watch and the console are one code.

Samples at N options: the samples table has one column per scalar (z_h, z_r, b_r, theta,
distance). An N-option output is a vector with no faithful scalar — its leading option's value
is another quantity than the paper's signed opinion, and which option leads is not in the row —
so those columns stay NULL (`Output.value` None) and a reader of the samples never mistakes it
for the paper's ẑ_h. The hand, its landmarks and the arm's end effector are stored as at two
options; the vectors themselves are in a `--record` recording.
"""

from __future__ import annotations

import dataclasses
import functools
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, cast

import numpy as np

from services.core import messages as m
from services.core.node import Node, TopicPublisher
from services.experiment.presses import Box as Wire  # an option on the wire: colour or index
from services.model.geometry import COLOURS, Colour, OptionsLayout, TableLayout
from services.model.judge import Judge, OptionsTrialJudge, TrialJudge
from services.model.params import NodConfig
from services.model.protocol import Mode, TrialSpec, order_of, parse_order, with_order
from services.model.schedule import OptionsSchedule

Order = tuple[str, ...]  # O of each consensus trial, by name, in trial order


@dataclass(frozen=True, slots=True)
class Output:
    """One decision output for hand pose `src_seq`, whatever the number of options."""

    t_ns: int
    src_seq: int
    z: float | np.ndarray  # what the judge reads (ẑ_h: a number at two options, else a vector)
    value: float | None  # the samples' column and the console's bar; None at N (module doc)
    theta: float | None = None  # the observer's reading of the hand (the paper's ẑ_h only)
    distance: float | None = None

    @classmethod
    def of_signed(cls, msg: m.Opinions) -> Output:
        """The paper's signed output (an `Observed` ẑ_h carries θ and the distance too)."""
        z = msg.signed
        return cls(msg.t_ns, msg.src_seq, z, z,
                   getattr(msg, "theta", None), getattr(msg, "distance", None))


@dataclass(frozen=True, slots=True)
class ArmReading:
    """The arm's state as the conductor reads it: its trial, phase, target box, safety."""

    trial: int
    phase: str
    target: Wire | None
    ee: tuple[float, float]
    safe_stop: bool
    safety_reason: str


class Listener(Protocol):
    """What the conductor hears from the schema's keys, in neutral form."""

    def on_output(self, name: str, out: Output) -> None:
        """A decision output (`name`: z_h, z_r or b_r)."""

    def on_arm(self, arm: ArmReading) -> None:
        """The arm's state."""

    def on_press(self, trial: int, option: Wire) -> None:
        """The robot's press of a box in a trial (confirmed by the arm's state later)."""

    def on_layout(self, layout: Any) -> None:
        """The table the camera (or the sim) sees, judged from the next trial."""


class KeySpace(ABC):
    """What a session says differently by its number of options (module doc)."""

    cfg: NodConfig
    names: tuple[str, ...]

    @property
    def n_options(self) -> int:
        """How many options (boxes) the table has."""
        return len(self.names)

    @property
    @abstractmethod
    def trials(self) -> tuple[TrialSpec, ...]:
        """The trials the protocol's clock runs (index, gaze, gesture, level)."""

    @abstractmethod
    def trial(self, spec: TrialSpec) -> tuple[Mode, str | None]:
        """A clock trial's mode and O (by name; None in a dissensus trial)."""

    @abstractmethod
    def layout(self) -> Any:
        """The table until the camera (or the sim) says another."""

    @abstractmethod
    def judge(self, layout: Any, mode: Mode) -> Judge[Any, Any, Any]:
        """The judge of a trial on `layout`, from its "go"."""

    def publishers(self, node: Node) -> tuple[TopicPublisher, TopicPublisher]:
        """`experiment/trial` and `experiment/result`."""
        return node.publisher("experiment/trial"), node.publisher("experiment/result")

    def wire(self, node: Node, listener: Listener) -> None:
        """`vision/layout`, `decision/*`, `actuation/state|press`, each checked for our options."""

        def layout(msg: m.Layout) -> None:
            m.check_options(msg, self.names)
            listener.on_layout(self.table(msg))

        def output(name: str, msg: m.Opinions) -> None:
            m.check_options(msg, self.names)
            listener.on_output(name, self.output(msg))

        def arm(msg: m.ArmStateMsg) -> None:
            target = None if msg.target is None else self.box(msg.target)
            listener.on_arm(ArmReading(msg.trial, msg.phase, target, msg.ee, msg.safe_stop,
                                       msg.safety_reason))

        node.subscribe("vision/layout", layout)
        node.subscribe("decision/z_h", functools.partial(output, "z_h"))
        node.subscribe("decision/z_r", functools.partial(output, "z_r"))
        node.subscribe("decision/b_r", functools.partial(output, "b_r"))
        node.subscribe("actuation/state", arm)
        node.subscribe("actuation/press",
                       lambda msg: listener.on_press(msg.trial, self.box(msg.option)))

    @abstractmethod
    def table(self, msg: m.Layout) -> Any:
        """The table of a layout message as the judge reads it."""

    @abstractmethod
    def output(self, msg: m.Opinions) -> Output:
        """A decision output as the judge reads it."""

    @abstractmethod
    def name(self, option: Wire | None) -> str | None:
        """The name of an option as the judge carries it (None stays None)."""

    @abstractmethod
    def box(self, name: str) -> Wire:
        """An option name heard on the wire as the judge's box (MessageError: none of ours)."""

    @abstractmethod
    def summary(self) -> dict[str, Any]:
        """The session's configuration as stored with it."""

    @abstractmethod
    def order(self) -> Order:
        """The O of each consensus trial, by name, in trial order."""

    @abstractmethod
    def parse_order(self, text: str) -> Order:
        """An `--order` as given (ValueError, one line, if it is none of this schedule's)."""

    @abstractmethod
    def with_order(self, order: Order) -> KeySpace:
        """The same session with its consensus trials' O in `order` (gazes turned toward O)."""

    def trial_event(self, **fields: Any) -> dict[str, Any]:
        """The fields of a trial event (options by name), with the session's option set."""
        return {**fields, "options": self.names}

    def result(self, **fields: Any) -> dict[str, Any]:
        """The fields of a result (options by name), with the session's option set."""
        return {**fields, "options": self.names}


class PaperKeys(KeySpace):
    """The paper's study: red and blue, its trials and its two-option judge."""

    names = COLOURS

    def __init__(self, cfg: NodConfig) -> None:
        self.cfg = cfg

    @property
    def trials(self) -> tuple[TrialSpec, ...]:
        """The configuration's trials (mode and O in each)."""
        return tuple(self.cfg.protocol.trials)

    def trial(self, spec: TrialSpec) -> tuple[Mode, str | None]:
        """Mode and O as the paper's trial form carries them (O a colour, its name)."""
        return spec.mode, spec.option

    def layout(self) -> TableLayout:
        """The configuration's red and blue buzzers."""
        return self.cfg.layout

    def judge(self, layout: TableLayout, mode: Mode) -> TrialJudge:
        """The paper's judge (two-option kernel): O a colour, ẑ_h a number."""
        return TrialJudge(self.cfg, layout, mode)

    def table(self, msg: m.Layout) -> TableLayout:
        """The two boxes as red and blue."""
        return msg.paper_table()

    def output(self, msg: m.Opinions) -> Output:
        """The signed number of the vector (z, -z)."""
        return Output.of_signed(msg)

    def name(self, option: Wire | None) -> str | None:
        """A colour is its own name."""
        return None if option is None else str(option)

    def box(self, name: str) -> Colour:
        """Option 0 is red, option 1 blue."""
        return COLOURS[m.index_in(self.names, name)]

    def summary(self) -> dict[str, Any]:
        """The effective configuration, as the paper's sessions have always stored it."""
        return self.cfg.summary()

    def order(self) -> Order:
        """The O of each consensus trial of the configuration."""
        return order_of(self.cfg.protocol.trials)

    def parse_order(self, text: str) -> Order:
        """`red,blue,…` or letters `BRRBR` (`services.model.protocol.parse_order`)."""
        return parse_order(text, len(self.order()))

    def with_order(self, order: Order) -> PaperKeys:
        """The trials with their O in `order`, each gaze mirrored toward it."""
        colours = cast(tuple[Colour, ...], order)  # `with_order` refuses any but red and blue
        protocol = dataclasses.replace(
            self.cfg.protocol, trials=with_order(self.cfg.protocol.trials, colours)
        )
        return PaperKeys(dataclasses.replace(self.cfg, protocol=protocol))


class OptionKeys(KeySpace):
    """A table of three or more boxes: the schedule's trials, the judge over N (O a box index)."""

    def __init__(self, cfg: NodConfig, schedule: OptionsSchedule) -> None:
        self.cfg = cfg
        self.schedule = schedule
        self.names = schedule.names
        self._trials = schedule.timing_specs(self.layout())

    @property
    def trials(self) -> tuple[TrialSpec, ...]:
        """The clock's trials on the table (`OptionsSchedule.timing_specs`)."""
        return self._trials

    def trial(self, spec: TrialSpec) -> tuple[Mode, str | None]:
        """Mode and O from the schedule, by the trial's index."""
        t = self.schedule.trial(spec.index)
        return t.mode, self.schedule.name(t.option)

    def layout(self) -> OptionsLayout:
        """The configuration's table of N boxes (`NodConfig.table`)."""
        return self.cfg.table(self.n_options)

    def judge(self, layout: OptionsLayout, mode: Mode) -> OptionsTrialJudge:
        """The judge over N boxes: O a box index, ẑ_h a vector."""
        return OptionsTrialJudge(self.cfg, layout, mode)

    def table(self, msg: m.Layout) -> OptionsLayout:
        """The N boxes."""
        return msg.table()

    def output(self, msg: m.Opinions) -> Output:
        """The vector (no samples' scalar: the module doc)."""
        return Output(msg.t_ns, msg.src_seq, np.array(msg.values, dtype=float), None)

    def name(self, option: Wire | None) -> str | None:
        """Box j's name is the option set's j-th."""
        return None if option is None else self.names[int(option)]

    def box(self, name: str) -> int:
        """A name's box index."""
        return m.index_in(self.names, name)

    def summary(self) -> dict[str, Any]:
        """The configuration with the option set and its schedule (the analysis reads them)."""
        schedule = [dataclasses.asdict(t) for t in self.schedule.trials]  # for the analysis
        return {**self.cfg.summary(), "options": list(self.names), "option_schedule": schedule}

    def order(self) -> Order:
        """The O of each consensus trial of the schedule, by name."""
        return tuple(self.names[t.option] for t in self.schedule.trials
                     if t.mode == "consensus" and t.option is not None)

    def parse_order(self, text: str) -> Order:
        """Names (`red,green,blue`) or, when the names' initials differ, letters (`RGB`)."""
        return parse_names(text, self.names, len(self.order()))

    def with_order(self, order: Order) -> OptionKeys:
        """The schedule with its consensus trials' O in `order` (gazes follow O)."""
        it = iter(self.schedule.index_of(name) for name in order)
        trials = tuple(
            dataclasses.replace(t, option=next(it)) if t.mode == "consensus" else t
            for t in self.schedule.trials
        )
        return OptionKeys(self.cfg, dataclasses.replace(self.schedule, trials=trials))


def parse_names(text: str, names: Sequence[str], n: int) -> Order:
    """An order of `n` options by name, or by initial when no two names share one."""
    initials = {name[0].lower(): name for name in names}
    by = {name.lower(): name for name in names}
    if len(initials) == len(names):
        by |= initials
    raw = text.strip().lower()
    parts = [w.strip() for w in raw.split(",")] if "," in raw or raw in by else list(raw)
    if len(parts) != n or any(w not in by for w in parts):
        letters = "".join(name[0].upper() for name in names) if len(initials) == len(names) else ""
        raise ValueError(
            f"--order needs O for each of the {n} consensus trials, as {','.join(names)}"
            + (f" or letters such as {letters}" if letters else "") + f"; got {text!r}"
        )
    return tuple(by[w] for w in parts)


def key_space(cfg: NodConfig, schedule: OptionsSchedule | None) -> KeySpace:
    """The key space of a session: the paper's for two options (no schedule), else the N's."""
    return PaperKeys(cfg) if schedule is None else OptionKeys(cfg, schedule)

