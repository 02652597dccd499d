"""`nod sim`: a synthetic participant publishing hand poses exactly as vision would.

It stands in for the camera and the person: at camera rate it publishes 21 noisy landmarks on
`vision/hand`, and the table geometry on `vision/layout`. It watches the protocol (trial events),
the gaze cue (`eyes/cmd`) and the arm (`actuation/state`, `actuation/press`) the way a person
watches the rig, and its opinion (eq 2) steers the hand. Seeded: the same seed and the same
robot give the same participant. The participant is the default simulated person (the traits
fitted to the paper, `services.cohort.person`) unless `--params` sets `[participant]` keys.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
from typing import TYPE_CHECKING

import numpy as np

from services.cohort.person import fitted_traits
from services.core import messages as m
from services.core.cli import SEED, Parser, add_options_arg, add_service_args, fail
from services.core.config import load_with_options
from services.core.node import Node, TopicPublisher, setup_logging
from services.core.session import Fabric
from services.model.geometry import colour_sign
from services.model.params import NodConfig
from services.model.participant import Participant, jittered

if TYPE_CHECKING:  # imported at run time only with --render (it loads OpenCV)
    from services.scene.render import SceneRenderer

log = logging.getLogger("nod.sim")
NS = 1e-9


class SimService:
    """Wires a Participant to the rig's keys."""

    def __init__(
        self,
        node: Node,
        cfg: NodConfig,
        seed: int,
        rate_hz: float,
        cohort: bool,
        render: bool = False,
    ):
        self.node = node
        self.layout = cfg.layout
        rng = np.random.default_rng(seed)
        params = jittered(cfg.participant, rng) if cohort else cfg.participant
        self.person = Participant(params, cfg.layout, seed=int(rng.integers(2**31)))
        self.person.advance(node.clock.now_ns() * NS)  # at rest: only sets its clock
        self.option: str | None = None
        self.robot: str | None = None
        # --render: be the camera, not the tracker — frames go to `nod vision`, which publishes
        # the hand and the layout itself.
        self.renderer: SceneRenderer | None = None
        if render:
            from services.scene.render import SceneRenderer

            self.renderer = SceneRenderer(layout=cfg.layout, noise=2.0, seed=seed)
            self.pub_camera = node.publisher("sim/camera")
        else:
            self.pub_hand = node.publisher("vision/hand")
            self.pub_layout = node.publisher("vision/layout")
        node.subscribe("experiment/trial", self.on_trial)
        node.subscribe("eyes/cmd", self.on_gaze)
        node.subscribe("actuation/state", self.on_arm)
        node.subscribe("actuation/press", self.on_press)
        node.every(1.0 / rate_hz, self.frame)
        if not render:
            node.every(1.0, self.publish_layout)

    def on_gaze(self, msg: m.GazeMsg) -> None:
        """The participant sees where the eyes look (the attention gesture is not a cue)."""
        if not msg.gesture:
            self.person.see_gaze(msg.yaw)

    def on_trial(self, ev: m.TrialEvent) -> None:
        """Follow the protocol like a participant listening to the countdown."""
        t = self._advance(self.node.clock.now_ns())  # our clock, not the event's stamp
        if ev.phase == "setup":
            self.robot = None
            self.person.new_trial(ev.option)
        elif ev.phase == "go":
            self.person.go(t)
        elif ev.phase == "end":
            self.person.trial_ended(self.robot)  # type: ignore[arg-type]
        elif ev.phase == "interrupted":  # a void trial teaches nothing
            self.person.trial_ended(None)

    def on_arm(self, msg: m.ArmStateMsg) -> None:
        """Where the arm is heading, as the participant sees it."""
        heading = colour_sign(msg.target) if msg.target and msg.moving else 0
        self.person.see_robot(self.node.clock.now_ns() * NS, heading)

    def on_press(self, msg: m.PressMsg) -> None:
        """The robot pressed a buzzer."""
        self.robot = msg.colour

    def _advance(self, t_ns: int) -> float:
        t = t_ns * NS
        if t > self.person.t:
            self.person.advance(t)
        return self.person.t

    def frame(self, now_ns: int) -> None:
        """One camera frame: advance the person and publish the hand."""
        self._advance(now_ns)
        if self.renderer is not None:
            self._render(self.renderer, now_ns)
            return
        pts = self.person.landmarks()
        center = pts.mean(axis=0)
        self.pub_hand.put(
            t_ns=now_ns,
            detected=True,
            center=(float(center[0]), float(center[1])),
            landmarks=tuple((float(x), float(y)) for x, y in pts),
            source="sim",
        )

    def _render(self, renderer: SceneRenderer, now_ns: int) -> None:
        publish_frame(self.pub_camera, renderer, self.person.pos, now_ns)

    def publish_layout(self, now_ns: int) -> None:
        """The table geometry, for every service that needs the boxes."""
        self.pub_layout.put(t_ns=now_ns, **m.layout_fields(self.layout))


def publish_frame(
    pub: TopicPublisher, renderer: SceneRenderer, pos: np.ndarray, now_ns: int
) -> None:
    """One rendered camera frame with the hand at `pos`, as a JPEG on sim/camera."""
    import cv2

    image = renderer.render((float(pos[0]), float(pos[1])))
    ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])
    if ok:
        h, w = image.shape[:2]
        pub.put(t_ns=now_ns, jpeg=jpeg.tobytes(), width=w, height=h, hand_seq=pub.seq,
                detected=True)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod sim`."""
    p = Parser(
        prog="nod sim",
        description="Publish a synthetic participant's hand on vision/hand (stands in for vision).",
    )
    add_service_args(p)
    p.add_argument("--seed", type=SEED, default=1, help="random seed of the participant")
    p.add_argument("--rate", type=float, default=30.0, help="camera rate in Hz (default 30)")
    p.add_argument(
        "--cohort",
        action="store_true",
        help="draw person-to-person variation of the participant's traits from the seed",
    )
    p.add_argument(
        "--render",
        action="store_true",
        help="publish rendered camera frames on sim/camera (for `nod vision --source "
        "zenoh:sim/camera`) instead of hand poses",
    )
    add_options_arg(p)
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the sim participant until SIGINT/SIGTERM."""
    args = build_parser().parse_args(argv)
    setup_logging(args.verbose)
    try:
        if not 1.0 <= args.rate <= 1000.0:
            raise ValueError(f"--rate must be in [1, 1000] Hz, got {args.rate}")
        # the fitted person under the file's [participant], as `load_cohort_params` does
        cfg, schedule = load_with_options(args.params, args.options, fitted_traits())
        stands_in = () if args.render else ("vision",)
        node = Node("sim", Fabric.from_args(args), stands_in_for=stands_in, retry_s=math.inf)
    except (ValueError, OSError, ConnectionError) as exc:
        return fail("nod sim", exc)
    log.info("effective config: %s", json.dumps(cfg.summary("participant")))
    if schedule is not None:  # a table of 3+ boxes: the N_o-option person
        from services.sim.options_service import OptionsSimService

        layout = cfg.table(schedule.n_options)
        OptionsSimService(node, cfg, schedule, layout, args.seed, args.rate, args.cohort,
                          render=args.render)
    else:
        SimService(node, cfg, args.seed, args.rate, args.cohort, render=args.render)
    node.run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
