"""`nod actuation`: Algorithm 2 on z_r and hand poses, driving an arm behind a safety gate.

The behaviour state machine decides; the watchdog may veto: while any input has not arrived
within the stale bound (judged on this host's monotonic clock), a needed service's liveliness
is lost (the conductor's too, during a trial), the arm reports a device fault (a silent,
garbled or unplugged bus), or an e-stop is engaged, the arm holds its position and the state
key says why; the state also acknowledges the last e-stop command. The robot's press is
published once per trial.

One service for any number of options, on one key space (schema 3): z_r on `decision/z_r`,
the table on `vision/layout` and the protocol's events on `experiment/trial`, each checked
against the service's option set; each applied command on `actuation/cmd`, the arm's state on
`actuation/state` and the robot's press on `actuation/press`, the box by option name. What the
model does differently by the option count lives in one seam (`ArmSeam`, chosen by
`arm_seam`):

- `PaperArmSeam` (two options, the paper's kernel): z_r the signed number of the vector,
  `RobotTrial` over red and blue, any `ArmDriver` (sim or Feetech).
- `OptionsArmSeam` (N ≥ 3): z_r the vector, `OptionsRobotTrial` with the tie rule, the
  `OptionsSimArm` or the Feetech arm pressing box j at its arm file's pose of option j (a file
  without a pose for every option refused in one line).

The safety gate, Algorithm 2's timers, press detection, device-fault reporting and the e-stop
wiring are `ActuationService`'s, written once; its safety state goes out on `actuation/state`
whatever N (the e-stop's acknowledgement, `nod estop`, `nod status` and the recorders read it
there).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import sys
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any, Generic, NamedTuple, Protocol, TypeVar

import numpy as np

from services.actuation.drivers import (
    ARM_DRIVERS,
    check_arm_file,
    make_arm_driver,
    make_options_arm,
)
from services.core import messages as m
from services.core.cli import Parser, add_options_arg, add_service_args, fail
from services.core.config import load_with_options, option_names, params_hash
from services.core.node import Node, setup_logging
from services.core.priority import raise_priority
from services.core.session import Fabric
from services.model.arm import OptionsSimArm
from services.model.behaviour import ArmCommand, OptionsCommand
from services.model.geometry import COLOURS, Colour, OptionsLayout, Point, TableLayout
from services.model.params import NodConfig
from services.model.robot import OptionsRobotTrial, RobotTrial, TrialReactor
from services.model.safety import SafetyParams, Watchdog
from services.safety.latch_file import LatchFile, add_state_dir_arg, default_state_dir
from services.safety.wiring import run_device_service, watch_safety_inputs

log = logging.getLogger("nod.actuation")
NS = 1e-9

L = TypeVar("L", TableLayout, OptionsLayout)  # the table: red and blue, or N boxes
C = TypeVar("C", ArmCommand, OptionsCommand)  # an arm command: by colour, or by box index
B = TypeVar("B")  # a box as the model names it: a colour, or an option index
Z = TypeVar("Z")  # z_r: a number, or a vector over the options
B_co = TypeVar("B_co", covariant=True)


class ArmReport(Protocol[B_co]):
    """What the service reads of an arm's state (`ArmState`, `OptionsArmState`)."""

    @property
    def ee(self) -> Point:
        """The end effector in table coordinates."""

    @property
    def moving(self) -> bool:
        """Whether the end effector moves."""

    @property
    def target(self) -> B_co | None:
        """The box it heads for or presses."""

    @property
    def pressed(self) -> B_co | None:
        """The box it finished pressing this trial."""

    @property
    def fault(self) -> str | None:
        """Why the device refuses motion (its bus silent, garbled, unplugged), or None."""


class Arm(Protocol[C, B_co]):
    """An arm as the service drives it: by colour (`SimArm`, Feetech) or by box index."""

    def connect(self) -> None:
        """Open the connection (idempotent)."""

    def disconnect(self) -> None:
        """Close the connection (idempotent); callers hold the arm first."""

    def send(self, cmd: C) -> C:
        """Apply a command; return the one actually applied."""

    def home(self) -> C:
        """Back to the rest pose, the trial's press cleared."""

    def hold(self) -> C:
        """Safe stop: come to rest and hold."""

    def make_safe(self) -> object:
        """The arm's safe state (`hold`), for the service's end."""

    def state(self, t: float) -> ArmReport[B_co]:
        """The arm's state at time t (s)."""


# -- the seam: the paper's two-option kernel, or N boxes by index ---------------------------------


class ArmChoice(NamedTuple):
    """The arm the command line asked for: its driver, serial port and calibration file."""

    driver: str
    port: str | None = None
    arm_config: Path | None = None


class ArmSeam(ABC, Generic[L, C, B, Z]):
    """What actuation does differently by the option count (the module doc lists both).

    The service converts what it hears with `z_r` and `layout`, runs the `reactor` over
    `table`, drives the arm `make_arm` built, and names boxes on its keys with `name`.
    """

    table: L  # the table until the layout key says otherwise

    def __init__(self, cfg: NodConfig, names: tuple[str, ...]) -> None:
        self.names = names

    @classmethod
    def check_driver(cls, choice: ArmChoice, names: tuple[str, ...]) -> None:
        """Refuse (ValueError, one line) an arm this seam cannot drive (default: none)."""

    @classmethod
    @abstractmethod
    def make_arm(
        cls, choice: ArmChoice, cfg: NodConfig, names: tuple[str, ...], t0: float
    ) -> Arm[C, B]:
        """An unconnected arm for the table of options `names` (`t0`: the sim arm's start, s)."""

    @abstractmethod
    def reactor(self, cfg: NodConfig) -> TrialReactor[L, C, B, Z]:
        """Algorithm 2 over `table`, with the config's behaviour, debounce and trial timeout."""

    @abstractmethod
    def z_r(self, msg: m.Opinions) -> Z:
        """The robot's opinion as the model reads it (the message checked against our options)."""

    @abstractmethod
    def layout(self, msg: m.Layout) -> L:
        """The table as the model reads it (the message checked against our options)."""

    def arm_follows(self, arm: Arm[C, B], layout: L) -> None:
        """Give the arm a new trial's table (by default it keeps its own poses)."""

    @abstractmethod
    def name(self, box: B | None) -> str | None:
        """A box of the model by its option name (None stays None)."""

    @abstractmethod
    def aim(self, cmd: C) -> tuple[int, str | None]:
        """A command's lateral direction and target option as `actuation/cmd` carries them."""


class PaperArmSeam(ArmSeam[TableLayout, ArmCommand, Colour, float]):
    """The paper's two options: red and blue, z_r a signed number, any arm driver."""

    def __init__(self, cfg: NodConfig, names: tuple[str, ...]) -> None:
        super().__init__(cfg, names)
        if len(names) != 2:
            raise ValueError(f"the paper's robot presses one of two boxes, not {len(names)}")
        self.table = cfg.layout

    @classmethod
    def make_arm(
        cls, choice: ArmChoice, cfg: NodConfig, names: tuple[str, ...], t0: float
    ) -> Arm[ArmCommand, Colour]:
        """The `--driver` chosen: the sim arm, or a Feetech arm from its calibration file."""
        return make_arm_driver(*choice, cfg.layout, cfg.sim_arm, t0=t0)

    def reactor(self, cfg: NodConfig) -> RobotTrial:
        """The paper's robot (the two-option kernel of `services.model.robot`)."""
        return RobotTrial(self.table, cfg.behaviour, cfg.debounce, cfg.protocol.trial_timeout_s)

    def z_r(self, msg: m.Opinions) -> float:
        """z_r as the paper's signed number (> 0: option 0, red)."""
        m.check_options(msg, self.names)
        return msg.signed

    def layout(self, msg: m.Layout) -> TableLayout:
        """The two boxes as the paper's red and blue."""
        m.check_options(msg, self.names)
        return msg.paper_table()

    def name(self, box: Colour | None) -> str | None:
        """Red is option 0, blue option 1."""
        return None if box is None else self.names[COLOURS.index(box)]

    def aim(self, cmd: ArmCommand) -> tuple[int, str | None]:
        """Toward red (+1) or blue (-1), 0 at rest; the target by name."""
        return cmd.direction, self.name(cmd.target)


class OptionsArmSeam(ArmSeam[OptionsLayout, OptionsCommand, int, np.ndarray]):
    """Three or more options: N boxes by index, z_r a vector, any arm driver."""

    def __init__(self, cfg: NodConfig, names: tuple[str, ...]) -> None:
        super().__init__(cfg, names)
        self.table = cfg.table(len(names))

    @classmethod
    def check_driver(cls, choice: ArmChoice, names: tuple[str, ...]) -> None:
        """A Feetech arm file needs a press pose for every option.

        Checked before anything opens: a file calibrated for other boxes fails in one line
        naming the options it lacks.
        """
        if choice.driver == "feetech" and choice.arm_config is not None:
            check_arm_file(choice.arm_config, names)

    @classmethod
    def make_arm(
        cls, choice: ArmChoice, cfg: NodConfig, names: tuple[str, ...], t0: float
    ) -> Arm[OptionsCommand, int]:
        """The simulated arm, or the Feetech arm pressing box j at the pose of option j."""
        return make_options_arm(*choice, cfg.table(len(names)), names, cfg.sim_arm, t0=t0)

    def reactor(self, cfg: NodConfig) -> OptionsRobotTrial:
        """The robot over N boxes, with the dissensus tie rule."""
        return OptionsRobotTrial(
            self.table, cfg.behaviour, cfg.debounce, cfg.protocol.trial_timeout_s
        )

    def z_r(self, msg: m.Opinions) -> np.ndarray:
        """The vector z_r."""
        return msg.vector(self.names)

    def layout(self, msg: m.Layout) -> OptionsLayout:
        """The N boxes."""
        m.check_options(msg, self.names)
        return msg.table()

    def arm_follows(self, arm: Arm[OptionsCommand, int], layout: OptionsLayout) -> None:
        """The simulated arm heads for the boxes of the trial's table."""
        if isinstance(arm, OptionsSimArm):
            arm.layout = layout

    def name(self, box: int | None) -> str | None:
        """Box j is option j."""
        return None if box is None else self.names[box]

    def aim(self, cmd: OptionsCommand) -> tuple[int, str | None]:
        """No one lateral direction among N boxes; the target by name."""
        return 0, self.name(cmd.target)


def arm_seam(names: tuple[str, ...]) -> type[ArmSeam[Any, Any, Any, Any]]:
    """The seam of an option set: the paper's kernel for two options, N boxes above."""
    return PaperArmSeam if len(names) == 2 else OptionsArmSeam


# -- the service, once for every option set --------------------------------------------------------


class ActuationService(Generic[L, C, B, Z]):
    """Wires Algorithm 2, an arm and the safety watchdog to the rig's keys, for any N options."""

    def __init__(
        self,
        node: Node,
        cfg: NodConfig,
        arm: Arm[C, B],
        safety: SafetyParams,
        latch_file: LatchFile | None,
        names: tuple[str, ...] = COLOURS,
    ) -> None:
        """Drive `arm` (built by `arm_seam(names).make_arm`, connected) on the rig's keys."""
        self.node = node
        self.arm: Arm[C, B] = arm
        self.cfg = cfg
        self.names = tuple(names)
        self.seam: ArmSeam[L, C, B, Z] = arm_seam(self.names)(cfg, self.names)
        self.layout: L = self.seam.table
        self.robot: TrialReactor[L, C, B, Z] = self.seam.reactor(cfg)
        self.watchdog = Watchdog(safety, ("z_r", "hand"))
        # Stopped until the first check of the gate says otherwise: nothing reaches the arm before
        # the watchdog has judged its inputs once.
        self.safe_stop = True
        self.safety_reason = "starting"
        self.last_cmd: C | None = None
        # The service's own time (s) for Algorithm 2 and the arm: the rig clock, never a
        # message's timestamp (a peer's clock must not move the arm's timers), kept monotone.
        self._t = node.clock.now_ns() * NS
        self.pub_state = node.publisher("actuation/state")
        self.pub_cmd = node.publisher("actuation/cmd")
        self.pub_press = node.publisher("actuation/press")
        node.subscribe("decision/z_r", self.on_z_r)
        node.subscribe("vision/layout", self.on_layout)
        node.subscribe("experiment/trial", self.on_trial)
        node.subscribe("vision/hand", self.on_hand)
        watch_safety_inputs(
            node, self.watchdog, self.tick, latch_file, also_watch=("experiment",)
        )
        node.every(0.02, self.tick)

    # -- inputs --------------------------------------------------------------------------------

    def on_z_r(self, msg: m.Opinions) -> None:
        """A new robot opinion: one Algorithm 2 step (if it is fresh by the watchdog's rule).

        Converted first: a vector for another option set is refused before it counts as fresh
        input.
        """
        z_r = self.seam.z_r(msg)
        if self.node.feed_watchdog(self.watchdog, "z_r", msg.t_ns):
            self._step(z_r)

    def on_hand(self, pose: m.HandPose) -> None:
        """Watch for the human's press: any landmark inside a box."""
        if not self.node.feed_watchdog(self.watchdog, "hand", pose.t_ns):
            return
        if pose.detected:
            self.robot.see_hand(pose.landmarks)

    def on_layout(self, msg: m.Layout) -> None:
        """Use the geometry vision (or the sim) published (takes effect next trial)."""
        self.layout = self.seam.layout(msg)

    def on_trial(self, msg: m.TrialEvent) -> None:
        """Setup: home and reset; go: start Algorithm 2; end: the trial's choice is over.

        From setup to the end of a trial the conductor's liveliness is required too: without
        it nobody records the trial, so the robot must not press.
        """
        m.check_options(msg, self.names)
        ev = msg
        if ev.phase == "setup":
            self.robot.setup(ev.trial, self.layout)
            self.seam.arm_follows(self.arm, self.layout)
            self.watchdog.require("experiment", True)
            self.arm.state(self._now())
            if not self.safe_stop:
                self._send(self.arm.home())
        elif ev.phase == "go" and ev.trial == self.robot.trial:
            self._apply(self.robot.go(self._now()))
        elif ev.phase == "interrupted" and ev.trial == self.robot.trial:
            # The trial is void: forget its moves, so clearing the stop does not resume them.
            self.robot.interrupted()
            self.watchdog.require("experiment", False)
        elif ev.phase in ("end", "abort", "session_end"):
            self.watchdog.require("experiment", False)

    # -- control -------------------------------------------------------------------------------

    def _now(self) -> float:
        """The service's monotone time (s) on the rig clock."""
        self._t = max(self._t, self.node.clock.now_ns() * NS)
        return self._t

    def _step(self, z_r: Z | None) -> None:
        if not self.robot.running:
            return
        t = self._now()
        cmd = self.robot.step(t, z_r, self.arm.state(t).ee)
        if cmd is not None:
            self._apply(cmd)

    def _apply(self, cmd: C) -> None:
        """Send the behaviour's command unless the safety gate holds the arm."""
        if self.safe_stop:
            return
        last = self.last_cmd
        # Only changes reach the arm; the reason text alone is not a new command (a paper
        # command's direction follows from its target, so action and target say it all).
        if last is None or (cmd.action, cmd.target) != (last.action, last.target):
            self._send(self.arm.send(cmd))

    def _send(self, applied: C) -> None:
        """Every applied command on `actuation/cmd` (changes only: `_apply` filters)."""
        self.last_cmd = applied
        direction, target = self.seam.aim(applied)
        self.pub_cmd.put(action=applied.action, direction=direction, target=target,
                         reason=applied.reason[:200])

    def tick(self, now_ns: int) -> None:
        """Periodic: safety gate, timers of Algorithm 2, arm state and the robot's press."""
        # A faulted device (a bus silent, garbled, unplugged; a simulated fault) is a safety
        # stop like a stale input, for every arm and every number of options: the conductor
        # sees it on the state key and interrupts the trial.
        self.watchdog.set_fault(self.arm.state(self._now()).fault)
        status = self.watchdog.check(self.node.arrival_ns())
        if status.safe_stop and not self.safe_stop:
            log.warning("SAFE STOP: %s", status.reason)
            self._send(self.arm.hold())
        elif not status.safe_stop and self.safe_stop:
            log.info("safety clear: resuming")
            self.last_cmd = None  # re-send the behaviour's current command
            if not self.robot.running and self.robot.trial:  # between trials: the rest pose
                self._send(self.arm.home())
        self.safe_stop, self.safety_reason = status.safe_stop, status.reason
        if not self.safe_stop:
            self._step(None)
        state = self.arm.state(self._now())
        if state.pressed is not None and self.robot.arm_pressed(state.pressed):
            pressed = self.seam.name(state.pressed)
            self.pub_press.put(option=pressed, trial=self.robot.trial)
            log.info("trial %d: robot pressed %s", self.robot.trial, pressed)
        phase = self.robot.machine.phase
        self.pub_state.put(
            ee=state.ee,
            phase=phase,
            moving=state.moving,
            target=self.seam.name(state.target),
            safe_stop=self.safe_stop,
            safety_reason=self.safety_reason[:400],
            fault=(state.fault or "")[:400],
            estop=self.watchdog.estopped,
            estop_id=self.watchdog.estop_id,
            trial=self.robot.trial,
        )


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod actuation`."""
    p = Parser(
        prog="nod actuation",
        description="Run Algorithm 2 on z_r and hand poses and drive the arm (default: sim arm).",
    )
    add_service_args(p)
    p.add_argument("--driver", choices=ARM_DRIVERS, default="sim", help="arm driver (default sim)")
    p.add_argument("--port", default=None, help="serial port of a real arm (e.g. /dev/ttyACM0)")
    p.add_argument(
        "--arm-config", type=Path, default=None, help="arm file with calibrated poses (feetech)"
    )
    p.add_argument("--stale-ms", type=float, default=None, help="input staleness bound (ms)")
    add_state_dir_arg(p)
    add_options_arg(p)
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the actuation service until SIGINT/SIGTERM (`calibrate` records arm poses)."""
    if argv is None:
        argv = sys.argv[1:]
    if argv[:1] == ["calibrate"]:
        from services.actuation.calibrate import main as calibrate

        return calibrate(argv[1:])
    args = build_parser().parse_args(argv)
    setup_logging(args.verbose)
    try:
        cfg, schedule = load_with_options(args.params, args.options)
        names = option_names(schedule)
        choice = ArmChoice(args.driver, args.port, args.arm_config)
        arm_seam(names).check_driver(choice, names)  # before opening
        safety = cfg.safety
        if args.stale_ms is not None:
            safety = dataclasses.replace(safety, stale_ms=args.stale_ms)
        latch_file = LatchFile(args.state_dir or default_state_dir(), args.rig, "actuation")
        latch_file.check_writable()  # an arm whose e-stop cannot survive a restart does not start
        node = Node(
            "actuation", Fabric.from_args(args), retry_s=math.inf, params_hash=params_hash(cfg)
        )
    except (ValueError, OSError, ConnectionError) as exc:
        return fail("nod actuation", exc)
    log.info("effective config: %s", json.dumps(cfg.summary("behaviour", "sim_arm", "safety")))
    raise_priority("actuation")  # once its configuration is good: errors stay one line
    try:
        arm: Arm[Any, Any] = arm_seam(names).make_arm(choice, cfg, names, node.clock.now_ns() * NS)
        arm.connect()
    except (ValueError, OSError, ConnectionError) as exc:
        node.close()
        return fail("nod actuation", exc)
    ActuationService(node, cfg, arm, safety, latch_file, names)
    run_device_service(node, arm)  # the arm holds however the service ends
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
