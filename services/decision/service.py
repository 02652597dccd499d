"""`nod decision`: hand poses in, ẑ_h / z_r / b_r out (Algorithm 1 on the fabric).

On every accepted hand pose the engine advances eqs 1-2 (and eq 6 in consensus trials) to the
pose's own timestamp and publishes the three quantities with `src_seq` = the pose's `seq`,
whether or not a trial is running. Trial events reset the state and set the mode and option O.

One service for any number of options. The engine is chosen by the option count: the paper's
`DecisionModel` (the two-option kernel, numbers) for two, `OptionsDecision` (vectors) for more.
What differs lives in one seam, the key space (`DecisionKeys`), picked by `key_space`:

- `PaperDecisionKeys` (schema 1): `decision/z_h` (an `Observed`, with θ and the distance),
  `decision/z_r`, `decision/b_r` numbers; `vision/layout` (taken at once, the state kept) and
  `experiment/trial` (O a colour); the engine's look-ahead of the next interval's RK4 steps.
- `OptionsDecisionKeys` (schema 2): `options/z_h|z_r|b_r` vectors; `options/layout` and
  `options/trial` (O a box index), each checked against N; a new table takes effect at the next
  trial's setup (a new engine over it).

The time handling — a pose from the future refused, one out of order ignored, z_r published
before the pose is read — and the trial handling are `DecisionService`'s, written once.
Unifying the key spaces (issue 34, step 3) replaces the seam and nothing else.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from typing import Any, ClassVar, Generic, NamedTuple, TypeVar

from services.core import messages as m
from services.core.cli import fail, service_parser
from services.core.config import load_with_options, params_hash
from services.core.node import Node, setup_logging
from services.core.session import Fabric
from services.model.decision import (
    DecisionModel,
    DecisionOutput,
    OptionsDecision,
    OptionsDecisionOutput,
)
from services.model.geometry import Point
from services.model.params import NodConfig
from services.model.protocol import Mode

log = logging.getLogger("nod.decision")

E = TypeVar("E", DecisionModel, OptionsDecision)  # the engine: the paper's kernel, or N options
Handler = Callable[[Any], None]  # a subscriber's handler: the message type is the key's
Landmarks = Sequence[Point]  # a hand pose's landmarks


class TrialCue(NamedTuple):
    """What the decision engine reads of a trial event, whatever key space carried it."""

    phase: str
    trial: int
    mode: Mode
    option: Any  # O as the engine names it: a colour, or an option index (None: none)


# -- the seam: one key space each ----------------------------------------------------------------


class DecisionKeys(ABC, Generic[E]):
    """Everything the decision service does differently in one key space (module doc)."""

    schema: ClassVar[int]  # the messages' schema version

    @abstractmethod
    def __init__(self, node: Node, cfg: NodConfig, n_options: int) -> None:
        """The space's publishers on `node`, for a table of `n_options` boxes from `cfg`."""

    @abstractmethod
    def engine(self) -> E:
        """A fresh engine over the table in use."""

    @abstractmethod
    def subscribe(self, node: Node, on_layout: Handler, on_trial: Handler) -> None:
        """The table (vision, sim) and the protocol's events (the conductor)."""

    @abstractmethod
    def trial(self, msg: Any) -> TrialCue:
        """A trial event's phase, trial, mode and O (MessageError: not for this table)."""

    @abstractmethod
    def use_layout(self, engine: E, msg: Any) -> None:
        """A layout message (MessageError: not for this table): the table from now on."""

    def at_setup(self, engine: E) -> E:
        """The engine for a new trial (by default the same one: its reset starts the trial)."""
        return engine

    @abstractmethod
    def publish_z_r(self, engine: E, t_ns: int, src_seq: int) -> None:
        """z_r at the pose's time, before the pose is read (what the arm waits for)."""

    @abstractmethod
    def read(self, engine: E, landmarks: Landmarks | None, t_ns: int, src_seq: int) -> None:
        """Read the pose into the engine (`PoseEngine.read`), then publish ẑ_h and b_r."""

    def look_ahead(self, engine: E) -> None:
        """Work the engine can do before the next pose arrives (by default none)."""


class PaperDecisionKeys(DecisionKeys[DecisionModel]):
    """The paper's keys (schema 1): red and blue, numbers, `DecisionModel`."""

    schema = m.SCHEMA_VERSION

    def __init__(self, node: Node, cfg: NodConfig, n_options: int = 2) -> None:
        if n_options != 2:
            raise ValueError(f"the paper's keys carry two options, not {n_options}")
        self.params = cfg.decision
        self.table = cfg.layout
        self.pub_zh = node.publisher("decision/z_h")
        self.pub_zr = node.publisher("decision/z_r")
        self.pub_br = node.publisher("decision/b_r")

    def engine(self) -> DecisionModel:
        """The paper's engine (the two-option kernel the study's golden holds bit for bit)."""
        return DecisionModel(self.params, self.table)

    def subscribe(self, node: Node, on_layout: Handler, on_trial: Handler) -> None:
        """`vision/layout`, `experiment/trial`."""
        node.subscribe("vision/layout", on_layout)
        node.subscribe("experiment/trial", on_trial)

    def trial(self, msg: m.TrialEvent) -> TrialCue:
        """An `experiment/trial` event (O a colour)."""
        return TrialCue(msg.phase, msg.trial, msg.mode, msg.option)

    def use_layout(self, engine: DecisionModel, msg: m.Layout) -> None:
        """The observer reads later poses against it at once (state and ẑ_h kept)."""
        self.table = m.layout_from_msg(msg)
        engine.set_layout(self.table)

    def publish_z_r(self, engine: DecisionModel, t_ns: int, src_seq: int) -> None:
        """`decision/z_r`."""
        self.pub_zr.put(t_ns=t_ns, value=engine.z_r, src_seq=src_seq)

    def read(
        self, engine: DecisionModel, landmarks: Landmarks | None, t_ns: int, src_seq: int
    ) -> None:
        """`decision/z_h` with what it was read from (θ, distance), then `decision/b_r`."""
        out: DecisionOutput = engine.read(landmarks)
        obs = out.observation
        self.pub_zh.put(
            t_ns=t_ns, value=out.z_hat, src_seq=src_seq, theta=obs.theta, distance=obs.distance
        )
        self.pub_br.put(t_ns=t_ns, value=out.b_r, src_seq=src_seq)

    def look_ahead(self, engine: DecisionModel) -> None:
        """The next interval's full RK4 steps, while no pose waits (`DecisionModel.look_ahead`)."""
        engine.look_ahead()


class OptionsDecisionKeys(DecisionKeys[OptionsDecision]):
    """The `options/*` keys (schema 2): N options by index, vectors, `OptionsDecision`."""

    schema = m.OPTIONS_SCHEMA_VERSION

    def __init__(self, node: Node, cfg: NodConfig, n_options: int) -> None:
        self.params = cfg.decision
        self.n = n_options
        self.table = cfg.table(n_options)
        self.pub_zh = node.publisher("options/z_h")
        self.pub_zr = node.publisher("options/z_r")
        self.pub_br = node.publisher("options/b_r")

    def engine(self) -> OptionsDecision:
        """The engine over N options."""
        return OptionsDecision(self.table, self.params)

    def subscribe(self, node: Node, on_layout: Handler, on_trial: Handler) -> None:
        """`options/layout`, `options/trial`."""
        node.subscribe("options/layout", on_layout)
        node.subscribe("options/trial", on_trial)

    def trial(self, msg: m.OptionsTrialEvent) -> TrialCue:
        """An `options/trial` event (O a box index), refused when it is for another N."""
        m.check_count(msg, self.n)
        return TrialCue(msg.phase, msg.trial, msg.mode, msg.option)

    def use_layout(self, engine: OptionsDecision, msg: m.OptionsLayoutMsg) -> None:
        """The boxes for the next trial (refused when they are not N): see `at_setup`."""
        self.table = m.same_count(msg.layout(), self.n)

    def at_setup(self, engine: OptionsDecision) -> OptionsDecision:
        """A new engine when the table changed (its observer's boxes are fixed at build)."""
        return engine if engine.layout is self.table else self.engine()

    def publish_z_r(self, engine: OptionsDecision, t_ns: int, src_seq: int) -> None:
        """`options/z_r`."""
        self.pub_zr.put(t_ns=t_ns, values=tuple(engine.z_r.tolist()), src_seq=src_seq)

    def read(
        self, engine: OptionsDecision, landmarks: Landmarks | None, t_ns: int, src_seq: int
    ) -> None:
        """`options/z_h`, then `options/b_r`."""
        out: OptionsDecisionOutput = engine.read(landmarks)
        self.pub_zh.put(t_ns=t_ns, values=tuple(out.z_hat.tolist()), src_seq=src_seq)
        self.pub_br.put(t_ns=t_ns, values=tuple(out.b_r.tolist()), src_seq=src_seq)


def key_space(n_options: int) -> type[DecisionKeys[Any]]:
    """The key space of a table of `n_options` boxes: the paper's for two, `options/*` above."""
    return PaperDecisionKeys if n_options == 2 else OptionsDecisionKeys


# -- the service, once for every key space -------------------------------------------------------


class DecisionService(Generic[E]):
    """Wires the decision engine for `n_options` options to the rig's keys."""

    def __init__(
        self, node: Node, cfg: NodConfig | None = None, n_options: int = 2
    ) -> None:
        """The engine of `cfg.decision` over the table of `n_options` boxes (default config)."""
        cfg = cfg if cfg is not None else NodConfig()
        self.node = node
        self.keys: DecisionKeys[E] = key_space(n_options)(node, cfg, n_options)
        self.model: E = self.keys.engine()
        self.skew_ns = cfg.safety.skew_ms * 1e6
        self.future = 0  # poses refused for a stamp ahead of our clock
        self.out_of_order = 0  # poses ignored for a stamp not newer than the last one
        self._last_seq: int | None = None
        node.subscribe("vision/hand", self.on_hand)
        self.keys.subscribe(node, self.on_layout, self.on_trial)

    def on_hand(self, pose: m.HandPose) -> None:
        """Advance the dynamics to the pose's time and publish ẑ_h, z_r, b_r."""
        ahead = self.node.offset_ns(pose.t_ns)
        if ahead > self.skew_ns:
            # A pose from the future (a fast clock or a forged stamp) would drag the model's
            # time ahead and freeze it against every later pose: refuse it.
            self.future += 1
            if self.future <= 10 or self.future % 100 == 0:
                log.warning(
                    "hand pose seq %d stamped %.0f ms ahead of our clock; refused (#%d)",
                    pose.seq, ahead / 1e6, self.future,
                )
            return
        if not self.model.accepts(pose.t_ns):
            self.out_of_order += 1  # stale or reordered pose: time never runs backwards
            if self.out_of_order <= 10 or self.out_of_order % 100 == 0:
                log.warning("hand pose seq %d is not newer than the last one; ignored", pose.seq)
            return
        # z_r first, before the pose is even read: it is what the arm waits for, and at the
        # pose's time it depends only on the interval before (ẑ_h held). Published with the
        # pose's timestamp: the values describe the state at that instant.
        self.model.advance(pose.t_ns)
        self.keys.publish_z_r(self.model, pose.t_ns, pose.seq)
        self.keys.read(
            self.model, pose.landmarks if pose.detected else None, pose.t_ns, pose.seq
        )
        if self._last_seq is not None and pose.seq > self._last_seq + 1:
            log.debug("hand poses %d..%d missing", self._last_seq + 1, pose.seq - 1)
        self._last_seq = pose.seq
        self.keys.look_ahead(self.model)  # while no pose waits

    def on_layout(self, msg: Any) -> None:
        """Use the geometry vision (or the sim) published (when: the key space's rule)."""
        self.keys.use_layout(self.model, msg)

    def on_trial(self, msg: Any) -> None:
        """Reset at setup and at "go": opinions form from the cue on (Algorithm 1 trigger)."""
        ev = self.keys.trial(msg)
        if ev.phase == "setup":
            self.model = self.keys.at_setup(self.model)
        if self.model.on_trial(ev.phase, ev.mode, ev.option):
            option = ev.option if ev.mode == "consensus" else None
            log.info("trial %d %s: mode=%s O=%s", ev.trial, ev.phase, ev.mode, option)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod decision`."""
    return service_parser(
        "nod decision",
        "Observe the human opinion (eq 7), integrate the robot opinion (eq 1) and "
        "its bias (eq 6), publish ẑ_h, z_r and b_r on every hand pose.",
        options=True,
    )


def main(argv: list[str] | None = None) -> int:
    """Run the decision service until SIGINT/SIGTERM."""
    args = build_parser().parse_args(argv)
    setup_logging(args.verbose)
    try:
        cfg, schedule = load_with_options(args.params, args.options)
        node = Node(
            "decision", Fabric.from_args(args), retry_s=math.inf, params_hash=params_hash(cfg)
        )
    except (ValueError, OSError, ConnectionError) as exc:
        return fail("nod decision", exc)
    log.info("effective config: %s", json.dumps(cfg.summary("decision")))
    DecisionService(node, cfg, 2 if schedule is None else schedule.n_options)
    node.run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
