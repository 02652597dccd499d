"""`nod sim`: a synthetic participant publishing hand poses exactly as vision would.

It stands in for the camera and the person: at camera rate it publishes 21 noisy landmarks on
`vision/hand`, and the table geometry on the layout key. It watches the protocol (trial events),
the gaze cue (`eyes/cmd`) and the arm (its state and its press) the way a person watches the rig,
and its opinion (eq 2) steers the hand. Seeded: the same seed and the same robot give the same
participant. The participant is the default simulated person (the traits fitted to the paper,
`services.cohort.person`) unless `--params` sets `[participant]` keys.

One service for any number of options (`--options N`, or a params file's list), on one key
space (schema 3: options by name, each message checked against the sim's option set): the
person is one `Participant` at the table of N boxes, and the keys, loop, timing, rendering and
trial handling below are written once. What differs with N is only how the person names an
option, `SimSeam`: the paper's person (the two-option kernel) by colour, the arm's heading a
sign; the person at N boxes by box index. `sim_seam` picks one by the option count.

With `--render` it is the camera instead: frames of the table (N boxes, each in its option's
colour, `services.scene.option_colours`) on `sim/camera`, for `nod vision`, which publishes the
hand and the table itself.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, Any, Generic

import numpy as np

from services.cohort.person import fitted_traits
from services.core import messages as m
from services.core.cli import SEED, fail, service_parser
from services.core.config import load_with_options
from services.core.node import Node, TopicPublisher, setup_logging
from services.core.session import Fabric
from services.model.gaze import GazeCommand
from services.model.geometry import COLOURS, Box, Colour, OptionsLayout, TableLayout, colour_sign
from services.model.params import NodConfig
from services.model.participant import Opt, Participant, ParticipantParams, jittered
from services.model.schedule import OptionsSchedule

if TYPE_CHECKING:  # imported at run time only with --render (it loads OpenCV)
    from services.scene.render import SceneRenderer

log = logging.getLogger("nod.sim")
NS = 1e-9
Painted = tuple[tuple[Box, tuple[int, int, int]], ...]


class SimSeam(ABC, Generic[Opt]):
    """How the person names options: the one place the sim differs by the option count."""

    def __init__(self, names: tuple[str, ...], layout: TableLayout | OptionsLayout) -> None:
        self.names = names
        self.layout = layout

    @abstractmethod
    def person(self, params: ParticipantParams, seed: int) -> Participant[Opt]:
        """The person at this table."""

    @abstractmethod
    def option(self, name: str) -> Opt:
        """An option name as the person names it (MessageError: none of ours)."""

    @abstractmethod
    def heading(self, target: str | None, moving: bool) -> int | None:
        """Where an arm state says the arm heads, in the person's `see_robot` terms."""

    def layout_fields(self) -> dict[str, Any]:
        """The fields of `vision/layout`: the option set, its boxes and the commit line."""
        return m.layout_fields(self.names, self.layout)

    @abstractmethod
    def painted(self) -> Painted | None:
        """The boxes a rendered frame paints in their options' colours (None: the paper's)."""


class PaperSeam(SimSeam[Colour]):
    """The paper's two options: colours, the arm's heading a sign."""

    layout: TableLayout

    def person(self, params: ParticipantParams, seed: int) -> Participant[Colour]:
        """The paper's person on its table (`TableLayout`): options are colours."""
        return Participant(params, self.layout, seed=seed)

    def option(self, name: str) -> Colour:
        """Option 0 is red, option 1 blue."""
        return COLOURS[m.index_in(self.names, name)]

    def heading(self, target: str | None, moving: bool) -> int:
        """+1 toward red, −1 toward blue, 0 still: the paper's sign."""
        return colour_sign(self.option(target)) if target and moving else 0

    def painted(self) -> None:
        """The renderer's own red and blue buzzers."""
        return None


class OptionsSeam(SimSeam[int]):
    """Three or more options: box indices."""

    layout: OptionsLayout

    def person(self, params: ParticipantParams, seed: int) -> Participant[int]:
        """The person at the N boxes (`OptionsLayout`): options are box indices."""
        return Participant(params, self.layout, seed)

    def option(self, name: str) -> int:
        """A name's box index."""
        return m.index_in(self.names, name)

    def heading(self, target: str | None, moving: bool) -> int | None:
        """The box the arm heads for, None when still."""
        return self.option(target) if target is not None and moving else None

    def painted(self) -> Painted:
        """Each box in its option's colour."""
        from services.scene.option_colours import painted_boxes

        return painted_boxes(self.names, self.layout)


def sim_seam(cfg: NodConfig, schedule: OptionsSchedule | None) -> SimSeam[Any]:
    """The seam for the option set: the paper's person for two options, box indices above."""
    if schedule is None:
        return PaperSeam(COLOURS, cfg.layout)
    return OptionsSeam(schedule.names, cfg.table(schedule.n_options))


class SimService(Generic[Opt]):
    """Wires a Participant to the rig's keys, for any option set."""

    def __init__(
        self,
        node: Node,
        cfg: NodConfig,
        seam: SimSeam[Opt],
        seed: int,
        rate_hz: float,
        cohort: bool,
        render: bool = False,
    ) -> None:
        self.node = node
        self.seam: SimSeam[Opt] = seam
        self.names = seam.names
        rng = np.random.default_rng(seed)
        params = jittered(cfg.participant, rng) if cohort else cfg.participant
        self.person: Participant[Opt] = seam.person(params, int(rng.integers(2**31)))
        self.person.advance(node.clock.now_ns() * NS)  # at rest: only sets its clock
        self.robot: Opt | None = None
        # --render: be the camera, not the tracker — frames go to `nod vision`, which publishes
        # the hand and the layout itself.
        self.renderer: SceneRenderer | None = None
        if render:
            from services.scene.render import SceneRenderer

            self.renderer = SceneRenderer(layout=cfg.layout, noise=2.0, seed=seed,
                                          options=seam.painted())
            self.pub_camera = node.publisher("sim/camera")
        else:
            self.pub_hand = node.publisher("vision/hand")
            self.pub_layout = node.publisher("vision/layout")
        node.subscribe("experiment/trial", self.on_trial)
        node.subscribe("actuation/state", self.on_arm)
        node.subscribe("actuation/press", self.on_press)
        node.subscribe("eyes/cmd", self.on_gaze)
        node.every(1.0 / rate_hz, self.frame)
        if not render:
            node.every(1.0, self.publish_layout)

    def on_gaze(self, msg: m.GazeMsg) -> None:
        """The participant sees where the eyes look (the attention gesture is not a cue).

        The full pose: on the paper's table the person reads its yaw only, as ever.
        """
        if not msg.gesture:
            self.person.see_gaze(GazeCommand(msg.yaw, msg.pitch))

    def on_trial(self, ev: m.TrialEvent) -> None:
        """Follow the protocol like a participant listening to the countdown."""
        m.check_options(ev, self.names)
        named = ev.option if ev.mode == "consensus" else None
        option = None if named is None else self.seam.option(named)
        t = self._advance(self.node.clock.now_ns())  # our clock, not the event's stamp
        if ev.phase == "setup":
            self.robot = None
            self.person.new_trial(option)
        elif ev.phase == "go":
            self.person.go(t)
        elif ev.phase == "end":
            self.person.trial_ended(self.robot)
        elif ev.phase == "interrupted":  # a void trial teaches nothing
            self.person.trial_ended(None)

    def on_arm(self, msg: m.ArmStateMsg) -> None:
        """Where the arm is heading, as the participant sees it."""
        heading = self.seam.heading(msg.target, msg.moving)
        self.person.see_robot(self.node.clock.now_ns() * NS, heading)

    def on_press(self, msg: m.PressMsg) -> None:
        """The robot pressed a box."""
        self.robot = self.seam.option(msg.option)

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
            t_ns=now_ns,
            detected=True,
            center=(float(center[0]), float(center[1])),
            landmarks=tuple((float(x), float(y)) for x, y in pts),
            source="sim",
        )

    def publish_layout(self, now_ns: int) -> None:
        """The table geometry, for every service that needs the boxes."""
        self.pub_layout.put(t_ns=now_ns, **self.seam.layout_fields())


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
    p = service_parser(
        "nod sim",
        "Publish a synthetic participant's hand on vision/hand (stands in for vision).",
        options=True,
    )
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
    SimService(node, cfg, sim_seam(cfg, schedule), args.seed, args.rate, args.cohort,
               render=args.render)
    node.run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
