"""`nod sim --options N`: a synthetic participant at a table of N boxes, on the fabric.

`services.sim.service` with the person at N_o boxes (`services.model.participant`): at
camera rate it publishes 21 noisy landmarks on `vision/hand` and the table (option names and
boxes) on `options/layout`; it follows `options/trial`, reads the gaze on `eyes/cmd` (the
geometric gaze toward a box, `services.model.gaze`), watches the arm on
`options/arm_state` and its press on `options/press`. Seeded as the two-option sim. With
`--render` it is the camera instead: frames of the table of N boxes (each in its option's
colour, `services.scene.option_colours`) on `sim/camera`, for `nod vision --options N`, which
publishes the hand and finds the boxes.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from services.core import messages as m
from services.core import options_messages as om
from services.core.node import Node
from services.core.options_messages import check_count, layout_message_fields
from services.model.gaze import GazeCommand
from services.model.geometry import OptionsLayout
from services.model.params import NodConfig
from services.model.participant import Participant, jittered
from services.model.schedule import OptionsSchedule
from services.sim.service import publish_frame

if TYPE_CHECKING:  # imported at run time only with --render (it loads OpenCV)
    from services.scene.render import SceneRenderer

log = logging.getLogger("nod.sim")
NS = 1e-9


class OptionsSimService:
    """Wires a Participant at N_o boxes to the rig's keys."""

    def __init__(
        self,
        node: Node,
        cfg: NodConfig,
        schedule: OptionsSchedule,
        layout: OptionsLayout,
        seed: int,
        rate_hz: float,
        cohort: bool,
        render: bool = False,
    ) -> None:
        self.node = node
        self.names = schedule.names
        self.layout = layout
        self.n = layout.n_options
        rng = np.random.default_rng(seed)
        params = jittered(cfg.participant, rng) if cohort else cfg.participant
        self.person = Participant(params, layout, int(rng.integers(2**31)))
        self.person.advance(node.clock.now_ns() * NS)  # at rest: only sets its clock
        self.robot: int | None = None
        self.renderer: SceneRenderer | None = None
        if render:  # the camera, not the tracker: `nod vision --options N` tracks the frames
            from services.scene.option_colours import painted_boxes
            from services.scene.render import SceneRenderer

            self.renderer = SceneRenderer(layout=cfg.layout, noise=2.0, seed=seed,
                                          options=painted_boxes(schedule.names, layout))
            self.pub_camera = node.publisher("sim/camera")
        else:
            self.pub_hand = node.publisher("vision/hand")
            self.pub_layout = node.publisher("options/layout")
        node.subscribe("options/trial", self.on_trial)
        node.subscribe("eyes/cmd", self.on_gaze)
        node.subscribe("options/arm_state", self.on_arm)
        node.subscribe("options/press", self.on_press)
        node.every(1.0 / rate_hz, self.frame)
        if not render:
            node.every(1.0, self.publish_layout)

    def on_gaze(self, msg: m.GazeMsg) -> None:
        """The participant sees where the eyes look (the attention gesture is not a cue)."""
        if not msg.gesture:
            self.person.see_gaze(GazeCommand(msg.yaw, msg.pitch))

    def on_trial(self, ev: om.OptionsTrialEvent) -> None:
        """Follow the protocol like a participant listening to the countdown."""
        check_count(ev, self.n)
        t = self._advance(self.node.clock.now_ns())
        if ev.phase == "setup":
            self.robot = None
            self.person.new_trial(ev.option if ev.mode == "consensus" else None)
        elif ev.phase == "go":
            self.person.go(t)
        elif ev.phase == "end":
            self.person.trial_ended(self.robot)
        elif ev.phase == "interrupted":
            self.person.trial_ended(None)

    def on_arm(self, msg: om.OptionsArmState) -> None:
        """Where the arm is heading, as the participant sees it."""
        check_count(msg, self.n)
        self.person.see_robot(self.node.clock.now_ns() * NS, msg.target if msg.moving else None)

    def on_press(self, msg: om.OptionsPress) -> None:
        """The robot pressed a box."""
        check_count(msg, self.n)
        self.robot = msg.option

    def _advance(self, t_ns: int) -> float:
        t = t_ns * NS
        if t > self.person.t:
            self.person.advance(t)
        return self.person.t

    def frame(self, now_ns: int) -> None:
        """One camera frame: advance the person and publish the hand."""
        self._advance(now_ns)
        if self.renderer is not None:
            publish_frame(self.pub_camera, self.renderer, self.person.pos, now_ns)
            return
        pts = self.person.landmarks()
        center = pts.mean(axis=0)
        self.pub_hand.put(
            t_ns=now_ns, detected=True, center=(float(center[0]), float(center[1])),
            landmarks=tuple((float(x), float(y)) for x, y in pts), source="sim",
        )

    def publish_layout(self, now_ns: int) -> None:
        """The table: option names and boxes, for every service that needs them."""
        self.pub_layout.put(t_ns=now_ns, **layout_message_fields(self.names, self.layout))
