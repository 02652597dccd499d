"""`nod decision`: hand poses in, ẑ_h / z_r / b_r out (Algorithm 1 on the fabric).

On every accepted hand pose the engine advances eqs 1-2 (and eq 6 in consensus trials) to the
pose's own timestamp and publishes the three quantities with `src_seq` = the pose's `seq`,
whether or not a trial is running. Trial events reset the state and set the mode and option O.

One service for any number of options, on one key space (schema 3): `decision/z_h` (an
`Observed`, with θ and the distance when the paper's observer read them), `decision/z_r` and
`decision/b_r` carry the option set and one value per option; `vision/layout` and
`experiment/trial` are checked against the service's option set. The engine is chosen by the
option count (`engine_seam`): the paper's `DecisionModel` (the two-option kernel the golden
holds bit for bit; its signed z goes out as (z, -z)) for two, `OptionsDecision` (vectors) for
more. What differs between the engines lives in one seam (`EngineSeam`):

- `PaperSeam`: a new table is taken at once (the state kept), O a colour, the engine's
  look-ahead of the next interval's RK4 steps.
- `OptionsSeam`: a new table takes effect at the next trial's setup (a new engine over it),
  O a box index.

The time handling — a pose from the future refused, one out of order ignored, z_r published
before the pose is read — and the trial handling are `DecisionService`'s, written once.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Any, Generic, NamedTuple, TypeVar

from services.core import messages as m
from services.core.cli import fail, service_parser
from services.core.config import load_with_options, option_names, params_hash
from services.core.node import Node, setup_logging
from services.core.session import Fabric
from services.model.decision import (
    DecisionModel,
    DecisionOutput,
    DecisionParams,
    OptionsDecision,
    OptionsDecisionOutput,
)
from services.model.geometry import COLOURS, Colour, Point
from services.model.params import NodConfig
from services.model.policy import PolicySettings, decision_for

log = logging.getLogger("nod.decision")

E = TypeVar("E", DecisionModel, OptionsDecision)  # the engine: the paper's kernel, or N options
Landmarks = Sequence[Point]  # a hand pose's landmarks


class Reading(NamedTuple):
    """One pose read by an engine: ẑ_h and b_r over the options, and what ẑ_h was read from."""

    z_h: tuple[float, ...]
    b_r: tuple[float, ...]
    theta: float | None = None
    distance: float | None = None


# -- the seam: the paper's two-option kernel, or the engine over N options ---------------------


class EngineSeam(ABC, Generic[E]):
    """What the decision service does differently by its engine (module doc)."""

    def __init__(self, cfg: NodConfig, names: tuple[str, ...]) -> None:
        self.params = cfg.decision
        self.names = names

    @abstractmethod
    def engine(self) -> E:
        """A fresh engine over the table in use."""

    @abstractmethod
    def option(self, name: str | None) -> Any:
        """O as the engine names it: a colour, or a box index (None stays None)."""

    @abstractmethod
    def use_layout(self, engine: E, layout: m.Layout) -> None:
        """A table (checked against our options): the table from now on."""

    def at_setup(self, engine: E) -> E:
        """The engine for a new trial (by default the same one: its reset starts the trial)."""
        return engine

    @abstractmethod
    def z_r(self, engine: E) -> tuple[float, ...]:
        """z_r over the options now."""

    @abstractmethod
    def read(self, engine: E, landmarks: Landmarks | None) -> Reading:
        """Read the pose into the engine (`PoseEngine.read`)."""

    def look_ahead(self, engine: E) -> None:
        """Work the engine can do before the next pose arrives (by default none)."""

    def retune(self, engine: E, params: DecisionParams) -> None:
        """Run the engine on a trial's parameters (a robot policy's b*, u_r): the paper's only.

        Any other engine runs on the params file's alone: asked for those, nothing to do.
        """
        if params != self.params:
            raise ValueError("a robot policy runs on the paper's two-option table only")


class PaperSeam(EngineSeam[DecisionModel]):
    """The paper's two options: `DecisionModel`, its signed z sent as (z, -z)."""

    def __init__(self, cfg: NodConfig, names: tuple[str, ...]) -> None:
        super().__init__(cfg, names)
        if len(names) != 2:
            raise ValueError(f"the paper's engine decides between two options, not {len(names)}")
        self.table = cfg.layout

    def engine(self) -> DecisionModel:
        """The paper's engine (the two-option kernel the study's golden holds bit for bit)."""
        return DecisionModel(self.params, self.table)

    def option(self, name: str | None) -> Colour | None:
        """Option j of the paper's table is COLOURS[j] to the kernel (z > 0: option 0)."""
        return None if name is None else COLOURS[m.index_in(self.names, name, "trial")]

    def use_layout(self, engine: DecisionModel, layout: m.Layout) -> None:
        """The observer reads later poses against it at once (state and ẑ_h kept)."""
        self.table = layout.paper_table()
        engine.set_layout(self.table)

    def z_r(self, engine: DecisionModel) -> tuple[float, ...]:
        """(z_r, -z_r)."""
        return (engine.z_r, -engine.z_r)

    def read(self, engine: DecisionModel, landmarks: Landmarks | None) -> Reading:
        """ẑ_h with what it was read from (θ, distance), and b_r."""
        out: DecisionOutput = engine.read(landmarks)
        obs = out.observation
        return Reading((out.z_hat, -out.z_hat), (out.b_r, -out.b_r), obs.theta, obs.distance)

    def look_ahead(self, engine: DecisionModel) -> None:
        """The next interval's full RK4 steps, while no pose waits (`DecisionModel.look_ahead`)."""
        engine.look_ahead()

    def retune(self, engine: DecisionModel, params: DecisionParams) -> None:
        """The kernel's own retune (its state kept: the trial's reset starts it anew)."""
        if params != engine.params:
            engine.retune(params)


class OptionsSeam(EngineSeam[OptionsDecision]):
    """Three or more options: `OptionsDecision` over vectors, O a box index."""

    def __init__(self, cfg: NodConfig, names: tuple[str, ...]) -> None:
        super().__init__(cfg, names)
        self.table = cfg.table(len(names))

    def engine(self) -> OptionsDecision:
        """The engine over N options."""
        return OptionsDecision(self.table, self.params)

    def option(self, name: str | None) -> int | None:
        """A name's box index."""
        return None if name is None else m.index_in(self.names, name, "trial")

    def use_layout(self, engine: OptionsDecision, layout: m.Layout) -> None:
        """The boxes for the next trial: see `at_setup`."""
        self.table = layout.table()

    def at_setup(self, engine: OptionsDecision) -> OptionsDecision:
        """A new engine when the table changed (its observer's boxes are fixed at build)."""
        return engine if engine.layout is self.table else self.engine()

    def z_r(self, engine: OptionsDecision) -> tuple[float, ...]:
        """The vector z_r."""
        return tuple(engine.z_r.tolist())

    def read(self, engine: OptionsDecision, landmarks: Landmarks | None) -> Reading:
        """ẑ_h and b_r (vectors)."""
        out: OptionsDecisionOutput = engine.read(landmarks)
        return Reading(tuple(out.z_hat.tolist()), tuple(out.b_r.tolist()))


def engine_seam(names: tuple[str, ...]) -> type[EngineSeam[Any]]:
    """The seam of an option set: the paper's kernel for two options, vectors above."""
    return PaperSeam if len(names) == 2 else OptionsSeam


# -- the service, once for every option set ------------------------------------------------------


class DecisionService(Generic[E]):
    """Wires the decision engine for `n_options` options to the rig's keys."""

    def __init__(
        self, node: Node, cfg: NodConfig | None = None, names: tuple[str, ...] = COLOURS
    ) -> None:
        """The engine of `cfg.decision` over the table of the options `names` (default config)."""
        cfg = cfg if cfg is not None else NodConfig()
        self.node = node
        self.envelope = cfg.policy
        self.settings: dict[int, PolicySettings] = {}  # a robot policy's, by trial (recent)
        self.trial = 0  # the trial set up last
        self.names = tuple(names)
        self.seam: EngineSeam[E] = engine_seam(self.names)(cfg, self.names)
        self.model: E = self.seam.engine()
        self.skew_ns = cfg.safety.skew_ms * 1e6
        self.future = 0  # poses refused for a stamp ahead of our clock
        self.out_of_order = 0  # poses ignored for a stamp not newer than the last one
        self._last_seq: int | None = None
        self.pub_zh = node.publisher("decision/z_h")
        self.pub_zr = node.publisher("decision/z_r")
        self.pub_br = node.publisher("decision/b_r")
        node.subscribe("vision/hand", self.on_hand)
        node.subscribe("vision/layout", self.on_layout)
        node.subscribe("experiment/trial", self.on_trial)
        node.subscribe("experiment/policy", self.on_policy)

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
        t_ns, seq, names = pose.t_ns, pose.seq, self.names
        self.pub_zr.put(t_ns=t_ns, options=names, values=self.seam.z_r(self.model), src_seq=seq)
        r = self.seam.read(self.model, pose.landmarks if pose.detected else None)
        self.pub_zh.put(t_ns=t_ns, options=names, values=r.z_h, src_seq=seq, theta=r.theta,
                        distance=r.distance)
        self.pub_br.put(t_ns=t_ns, options=names, values=r.b_r, src_seq=seq)
        if self._last_seq is not None and pose.seq > self._last_seq + 1:
            log.debug("hand poses %d..%d missing", self._last_seq + 1, pose.seq - 1)
        self._last_seq = pose.seq
        self.seam.look_ahead(self.model)  # while no pose waits

    def on_layout(self, msg: m.Layout) -> None:
        """Use the geometry vision (or the sim) published (when: the seam's rule)."""
        m.check_options(msg, self.names)
        self.seam.use_layout(self.model, msg)

    def on_policy(self, msg: m.PolicyMsg) -> None:
        """A robot policy's settings for a trial: its b* and u_r, from its setup (or its go).

        Checked against this service's own envelope (the params file's `[policy]`): settings
        outside it are refused, and the trial runs on the params file's own.
        """
        s = PolicySettings(msg.b_star, msg.gaze_level, msg.u_r)
        if not self.envelope.contains(s):
            raise ValueError(f"policy {msg.policy}: trial {msg.trial}'s b*={s.b_star:g}, "
                             f"u_r={s.u_r:g} lie outside [policy] {self.envelope}; refused")
        if len(self.names) != 2:
            raise ValueError("a robot policy runs on the paper's two-option table only; refused")
        self.settings[msg.trial] = s
        while len(self.settings) > 64:
            del self.settings[min(self.settings)]
        if msg.trial == self.trial:  # its trial is set up already: from now on
            self._tune(msg.trial)

    def _tune(self, trial: int) -> None:
        """The engine on trial `trial`'s parameters: its policy's settings, else the file's."""
        s = self.settings.get(trial)
        file = self.seam.params  # the params file's, which a trial without settings runs on
        self.seam.retune(self.model, file if s is None else decision_for(file, s))
        if s is not None:
            log.debug("trial %d: b*=%g, u_r=%g (robot policy)", trial, s.b_star, s.u_r)

    def on_trial(self, msg: m.TrialEvent) -> None:
        """Reset at setup and at "go": opinions form from the cue on (Algorithm 1 trigger)."""
        m.check_options(msg, self.names)
        option = self.seam.option(msg.option)
        if msg.phase == "setup":
            self.model = self.seam.at_setup(self.model)
        if msg.phase in ("setup", "go"):
            self.trial = msg.trial
            self._tune(msg.trial)
        if self.model.on_trial(msg.phase, msg.mode, option):
            shown = msg.option if msg.mode == "consensus" else None
            log.info("trial %d %s: mode=%s O=%s", msg.trial, msg.phase, msg.mode, shown)


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
    DecisionService(node, cfg, option_names(schedule))
    node.run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
