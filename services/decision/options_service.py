"""`nod decision --options N`: hand poses in, ẑ_h / z_r / b_r over N options out.

The N_o-option decision engine (`services.model.decision.OptionsDecision`) on the fabric, as
`services.decision.service` runs the paper's: every accepted hand pose advances the robot's
state to the pose's own timestamp and publishes the three vectors on `options/z_h`, `z_r`,
`b_r` (schema version 2) with `src_seq` = the pose's `seq`. `options/trial` events reset it
and set the mode and O; `options/layout` sets the boxes (the next trial's).
"""

from __future__ import annotations

import logging

from services.core import messages as m
from services.core import options_messages as om
from services.core.node import Node
from services.core.options_messages import check_count, same_count
from services.model.decision import DecisionParams, OptionsDecision
from services.model.geometry import OptionsLayout

log = logging.getLogger("nod.decision")


class OptionsDecisionService:
    """Wires an OptionsDecision to the rig's `options/*` keys."""

    def __init__(
        self, node: Node, params: DecisionParams, layout: OptionsLayout, skew_ms: float = 100.0
    ) -> None:
        self.node = node
        self.params = params
        self.model = OptionsDecision(layout, params)
        self.skew_ns = skew_ms * 1e6
        self.refused = 0
        self.pub_zh = node.publisher("options/z_h")
        self.pub_zr = node.publisher("options/z_r")
        self.pub_br = node.publisher("options/b_r")
        self._layout = layout
        node.subscribe("vision/hand", self.on_hand)
        node.subscribe("options/layout", self.on_layout)
        node.subscribe("options/trial", self.on_trial)

    def on_hand(self, pose: m.HandPose) -> None:
        """Advance to the pose's time and publish ẑ_h, z_r, b_r (stale or future: refused)."""
        future = self.node.offset_ns(pose.t_ns) > self.skew_ns
        if future or (self.model.t_ns is not None and pose.t_ns <= self.model.t_ns):
            self.refused += 1
            if self.refused <= 10 or self.refused % 100 == 0:
                log.warning("hand pose seq %d out of time order; refused (#%d)", pose.seq,
                            self.refused)
            return
        out = self.model.on_hand(pose.t_ns, pose.landmarks if pose.detected else None)
        self.pub_zr.put(t_ns=pose.t_ns, values=tuple(out.z_r.tolist()), src_seq=pose.seq)
        self.pub_zh.put(t_ns=pose.t_ns, values=tuple(out.z_hat.tolist()), src_seq=pose.seq)
        self.pub_br.put(t_ns=pose.t_ns, values=tuple(out.b_r.tolist()), src_seq=pose.seq)

    def on_layout(self, msg: om.OptionsLayoutMsg) -> None:
        """The boxes the sim (or vision) publishes; a table of another size is refused."""
        self._layout = same_count(msg.layout(), self.model.layout.n_options)

    def on_trial(self, ev: om.OptionsTrialEvent) -> None:
        """Reset at setup and at "go" (the new layout takes effect at setup)."""
        check_count(ev, self.model.layout.n_options)
        if ev.phase == "setup" and self._layout is not self.model.layout:
            self.model = OptionsDecision(self._layout, self.params)
        if ev.phase in ("setup", "go"):
            self.model.reset(ev.mode, ev.option if ev.mode == "consensus" else None)
            log.info("trial %d %s: mode=%s O=%s", ev.trial, ev.phase, ev.mode, self.model.option)
