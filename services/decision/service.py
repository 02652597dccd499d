"""`nod decision`: hand poses in, ẑ_h / z_r / b_r out (Algorithm 1 on the fabric).

On every accepted hand pose the model advances eqs 1-2 (and eq 6 in consensus trials) to the
pose's own timestamp and publishes the three values with `src_seq` = the pose's `seq`, whether or
not a trial is running. Trial events reset the state and set the mode and option O.
"""

from __future__ import annotations

import argparse
import json
import logging
import math

from services.core import messages as m
from services.core.cli import Parser, add_options_arg, add_service_args, fail
from services.core.config import load_with_options, params_hash
from services.core.node import Node, setup_logging
from services.core.session import Fabric
from services.model.decision import DecisionModel

log = logging.getLogger("nod.decision")


class DecisionService:
    """Wires a DecisionModel to the rig's keys."""

    def __init__(self, node: Node, model: DecisionModel, skew_ms: float = 100.0) -> None:
        self.node = node
        self.model = model
        self.skew_ns = skew_ms * 1e6
        self.future = 0
        self.pub_zh = node.publisher("decision/z_h")
        self.pub_zr = node.publisher("decision/z_r")
        self.pub_br = node.publisher("decision/b_r")
        self.out_of_order = 0
        self._last_seq: int | None = None
        node.subscribe("vision/hand", self.on_hand)
        node.subscribe("vision/layout", self.on_layout)
        node.subscribe("experiment/trial", self.on_trial)

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
        # pose's time it depends only on the interval before (ẑ_h held), whose full RK4 steps
        # `look_ahead` took after the previous pose. Published with the pose's timestamp: the
        # values describe the state at that instant.
        self.model.advance(pose.t_ns)
        self.pub_zr.put(t_ns=pose.t_ns, value=self.model.z_r, src_seq=pose.seq)
        out = self.model.read(pose.landmarks if pose.detected else None)
        obs = out.observation
        self.pub_zh.put(
            t_ns=pose.t_ns, value=out.z_hat, src_seq=pose.seq, theta=obs.theta,
            distance=obs.distance,
        )
        self.pub_br.put(t_ns=pose.t_ns, value=out.b_r, src_seq=pose.seq)
        if self._last_seq is not None and pose.seq > self._last_seq + 1:
            log.debug("hand poses %d..%d missing", self._last_seq + 1, pose.seq - 1)
        self._last_seq = pose.seq
        self.model.look_ahead()  # the next interval's steps, while no pose waits

    def on_layout(self, msg: m.Layout) -> None:
        """Use the geometry vision (or the sim) published."""
        self.model.set_layout(m.layout_from_msg(msg))

    def on_trial(self, ev: m.TrialEvent) -> None:
        """Reset at setup and at "go": opinions form from the cue on (Algorithm 1 trigger)."""
        if self.model.on_trial(ev.phase, ev.mode, ev.option):
            log.info(
                "trial %d %s: mode=%s O=%s", ev.trial, ev.phase, ev.mode, self.model.option
            )


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod decision`."""
    p = Parser(
        prog="nod decision",
        description="Observe the human opinion (eq 7), integrate the robot opinion (eq 1) and "
        "its bias (eq 6), publish ẑ_h, z_r and b_r on every hand pose.",
    )
    add_service_args(p)
    add_options_arg(p)
    return p


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
    if schedule is not None:  # a table of 3+ boxes: the N_o-option engine on options/* keys
        from services.decision.options_service import OptionsDecisionService

        layout = cfg.table(schedule.n_options)
        OptionsDecisionService(node, cfg.decision, layout, cfg.safety.skew_ms)
    else:
        DecisionService(node, DecisionModel(cfg.decision, cfg.layout), cfg.safety.skew_ms)
    node.run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
