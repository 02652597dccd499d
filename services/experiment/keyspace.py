"""The one seam between the conductor and its number of options: the session's key space.

`services.experiment.conductor.Conductor` is written once for any option set; what a session
says differently by its number of options lives here, chosen by the option count
(`key_space`):

- `PaperKeys`, the paper's study (two options, red and blue): the schema-1 keys
  (`experiment/trial`, `experiment/result`, `decision/z_h|z_r|b_r`, `actuation/state`,
  `actuation/press`, `vision/layout`), O a colour, ẑ_h a number, `TrialJudge`; its trials are
  the `TrialSpec`s of the configuration, which carry mode and O.
- `OptionKeys`, a table of three or more boxes: the `options/*` keys of schema 2
  (`services.core.messages`, schema 2), O a box index, ẑ_h a vector, `OptionsTrialJudge`; the
  clock runs `OptionsSchedule.timing_specs` and each trial's mode and O are the schedule's.

The conductor speaks in option *names* (what the store keeps, the console shows, the analysis
reads); a key space turns a name into what its messages carry (`trial_event`, `result`) and a
box of its messages or its judge back into a name (`name`). Readings come to the conductor in
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
from services.core.messages import check_count, same_count, values_for
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
    def of_scalar(cls, msg: m.Scalar) -> Output:
        """The paper's scalar output (an `Observed` ẑ_h carries θ and the distance too)."""
        return cls(msg.t_ns, msg.src_seq, msg.value, msg.value,
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

    @abstractmethod
    def publishers(self, node: Node) -> tuple[TopicPublisher, TopicPublisher]:
        """The session's trial-event and result keys.

        Each implementation names its keys in its `publisher` calls: the contract test reads
        the keys a service publishes from its code.
        """

    @abstractmethod
    def wire(self, node: Node, listener: Listener) -> None:
        """Subscribe the schema's decision, arm, press and layout keys for `listener`."""

    @abstractmethod
    def name(self, option: Wire | None) -> str | None:
        """The name of an option as the messages and the judge carry it (None stays None)."""

    @abstractmethod
    def on_wire(self, name: str | None) -> Wire | None:
        """An option name as the schema's messages carry it (None stays None)."""

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
        """The fields of a trial event (`option` by name) as the schema's message has them."""
        if "option" in fields:
            fields["option"] = self.on_wire(fields["option"])
        return fields

    def result(self, **fields: Any) -> dict[str, Any]:
        """The fields of a result (options by name) as the schema's message has them."""
        for key in ("option", "robot", "human"):
            if key in fields:
                fields[key] = self.on_wire(fields[key])
        return fields


class PaperKeys(KeySpace):
    """The paper's study: red and blue on the schema-1 keys, byte for byte as before the fold."""

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

    def publishers(self, node: Node) -> tuple[TopicPublisher, TopicPublisher]:
        """`experiment/trial` and `experiment/result`."""
        return node.publisher("experiment/trial"), node.publisher("experiment/result")

    def wire(self, node: Node, listener: Listener) -> None:
        """The schema-1 keys: `vision/layout`, `decision/*`, `actuation/state|press`."""
        node.subscribe("vision/layout", lambda msg: listener.on_layout(m.layout_from_msg(msg)))
        output = functools.partial(self._output, listener)
        node.subscribe("decision/z_h", functools.partial(output, "z_h"))
        node.subscribe("decision/z_r", functools.partial(output, "z_r"))
        node.subscribe("decision/b_r", functools.partial(output, "b_r"))
        node.subscribe("actuation/state", lambda msg: listener.on_arm(ArmReading(
            msg.trial, msg.phase, msg.target, msg.ee, msg.safe_stop, msg.safety_reason)))
        node.subscribe("actuation/press", lambda msg: listener.on_press(msg.trial, msg.colour))

    @staticmethod
    def _output(listener: Listener, name: str, msg: m.Scalar) -> None:
        listener.on_output(name, Output.of_scalar(msg))

    def name(self, option: Wire | None) -> str | None:
        """A colour is its own name."""
        return None if option is None else str(option)

    def on_wire(self, name: str | None) -> Wire | None:
        """A name is its colour on the paper's keys."""
        return name

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
    """A table of three or more boxes: the `options/*` keys of schema 2, O a box index."""

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

    def publishers(self, node: Node) -> tuple[TopicPublisher, TopicPublisher]:
        """`options/trial` and `options/result`."""
        return node.publisher("options/trial"), node.publisher("options/result")

    def wire(self, node: Node, listener: Listener) -> None:
        """The `options/*` keys, each vector and box count checked against N."""
        n = self.n_options

        def output(name: str, msg: m.OptionVector) -> None:
            listener.on_output(name, Output(msg.t_ns, msg.src_seq, values_for(msg, n), None))

        def arm(msg: m.OptionsArmState) -> None:
            check_count(msg, n)
            listener.on_arm(ArmReading(msg.trial, msg.phase, msg.target, msg.ee, msg.safe_stop,
                                       msg.safety_reason))

        def press(msg: m.OptionsPress) -> None:
            check_count(msg, n)
            listener.on_press(msg.trial, msg.option)

        def layout(msg: m.OptionsLayoutMsg) -> None:
            listener.on_layout(same_count(msg.layout(), n))

        node.subscribe("options/layout", layout)
        node.subscribe("options/z_h", lambda msg: output("z_h", msg))
        node.subscribe("options/arm_state", arm)
        node.subscribe("options/press", press)

    def name(self, option: Wire | None) -> str | None:
        """Box j's name is the option set's j-th."""
        return None if option is None else self.names[int(option)]

    def on_wire(self, name: str | None) -> Wire | None:
        """A name's box index."""
        return None if name is None else self.schedule.index_of(name)

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

    def trial_event(self, **fields: Any) -> dict[str, Any]:
        """With the option count its messages carry."""
        return {**super().trial_event(**fields), "n_options": self.n_options}

    def result(self, **fields: Any) -> dict[str, Any]:
        """With the option count its messages carry."""
        return {**super().result(**fields), "n_options": self.n_options}


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

