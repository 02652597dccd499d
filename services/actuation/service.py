"""`nod actuation`: Algorithm 2 on z_r and hand poses, driving an arm behind a safety gate.

The behaviour state machine decides; the watchdog may veto: while any input has not arrived
within the stale bound (judged on this host's monotonic clock), a needed service's liveliness
is lost (the conductor's too, during a trial), or an e-stop is engaged, the arm holds its
position and the state key says why; the state also acknowledges the last e-stop command. The
robot's press is published once per trial on `actuation/press`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import sys
from pathlib import Path

from services.actuation.drivers import ARM_DRIVERS, make_arm_driver
from services.core import messages as m
from services.core.cli import Parser, add_options_arg, add_service_args, fail
from services.core.config import load_with_options, params_hash
from services.core.node import Node, setup_logging
from services.core.priority import raise_priority
from services.core.session import Fabric
from services.model.arm import ArmDriver
from services.model.behaviour import ArmCommand
from services.model.params import NodConfig
from services.model.robot import RobotTrial
from services.model.safety import SafetyParams, Watchdog
from services.safety.latch_file import LatchFile, add_state_dir_arg, default_state_dir
from services.safety.wiring import watch_safety_inputs

log = logging.getLogger("nod.actuation")
NS = 1e-9


class ActuationService:
    """Wires Algorithm 2, an arm driver and the safety watchdog to the rig's keys."""

    def __init__(
        self,
        node: Node,
        cfg: NodConfig,
        arm: ArmDriver,
        safety: SafetyParams,
        latch_file: LatchFile | None,
    ) -> None:
        self.node = node
        self.layout = cfg.layout
        self.arm = arm
        self.cfg = cfg
        self.robot = RobotTrial(
            cfg.layout, cfg.behaviour, cfg.debounce, cfg.protocol.trial_timeout_s
        )
        self.watchdog = Watchdog(safety, ("z_r", "hand"))
        # Stopped until the first check of the gate says otherwise: nothing reaches the arm before
        # the watchdog has judged its inputs once.
        self.safe_stop = True
        self.safety_reason = "starting"
        self.last_cmd: ArmCommand | None = None
        # The service's own time (s) for Algorithm 2 and the arm: the rig clock, never a
        # message's timestamp (a peer's clock must not move the arm's timers), kept monotone.
        self._t = node.clock.now_ns() * NS
        self.pub_cmd = node.publisher("actuation/cmd")
        self.pub_state = node.publisher("actuation/state")
        self.pub_press = node.publisher("actuation/press")
        node.subscribe("decision/z_r", self.on_z_r)
        node.subscribe("vision/hand", self.on_hand)
        node.subscribe("vision/layout", self.on_layout)
        node.subscribe("experiment/trial", self.on_trial)
        watch_safety_inputs(
            node, self.watchdog, self.tick, latch_file, also_watch=("experiment",)
        )
        node.every(0.02, self.tick)

    # -- inputs --------------------------------------------------------------------------------

    def on_z_r(self, msg: m.Scalar) -> None:
        """A new robot opinion: one Algorithm 2 step (if it is fresh by the watchdog's rule)."""
        if self.node.feed_watchdog(self.watchdog, "z_r", msg.t_ns):
            self._step(msg.value)

    def on_hand(self, pose: m.HandPose) -> None:
        """Watch for the human's press: any landmark inside a buzzer box."""
        if not self.node.feed_watchdog(self.watchdog, "hand", pose.t_ns):
            return
        if pose.detected:
            self.robot.see_hand(pose.landmarks)

    def on_layout(self, msg: m.Layout) -> None:
        """Use the geometry vision (or the sim) published (takes effect next trial)."""
        self.layout = m.layout_from_msg(msg)

    def on_trial(self, ev: m.TrialEvent) -> None:
        """Setup: home and reset; go: start Algorithm 2; end: the trial's choice is over.

        From setup to the end of a trial the conductor's liveliness is required too: without
        it nobody records the trial, so the robot must not press.
        """
        if ev.phase == "setup":
            self.robot.setup(ev.trial, self.layout)
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

    def _step(self, z_r: float | None) -> None:
        if not self.robot.running:
            return
        t = self._now()
        cmd = self.robot.step(t, z_r, self.arm.state(t).ee)
        if cmd is not None:
            self._apply(cmd)

    def _apply(self, cmd: ArmCommand) -> None:
        """Send the behaviour's command unless the safety gate holds the arm."""
        if self.safe_stop:
            return
        last = self.last_cmd
        if last is None or (cmd.action, cmd.direction, cmd.target) != (
            last.action,
            last.direction,
            last.target,
        ):  # only changes reach the arm; the reason text alone is not a new command
            self._send(self.arm.send(cmd))

    def _send(self, applied: ArmCommand) -> None:
        self.last_cmd = applied
        self.pub_cmd.put(
            action=applied.action,
            direction=applied.direction,
            target=applied.target,
            reason=applied.reason[:200],
        )

    def tick(self, now_ns: int) -> None:
        """Periodic: safety gate, timers of Algorithm 2, arm state and the robot's press."""
        # A faulted bus (silent, garbled, unplugged) is a safety stop like a stale input: the
        # conductor sees it on the state key and interrupts the trial.
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
            self.pub_press.put(colour=state.pressed, trial=self.robot.trial)
            log.info("trial %d: robot pressed %s", self.robot.trial, state.pressed)
        self.pub_state.put(
            ee=state.ee,
            phase=self.robot.machine.phase,
            moving=state.moving,
            target=state.target,
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
        if schedule is not None and args.driver != "sim":
            raise ValueError(
                f"--options {schedule.n_options} runs the simulated arm only (--driver sim): no "
                "real arm is calibrated for more than two boxes yet"
            )
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
    if schedule is not None:  # a table of 3+ boxes: Algorithm 2 over N boxes, the sim arm
        from services.actuation.options_service import OptionsActuationService

        service = OptionsActuationService(
            node, cfg, cfg.table(schedule.n_options), safety, latch_file
        )
        node.on_forced_exit(service.arm.hold)
        try:
            node.run()
        finally:
            service.arm.hold()
        return 0
    try:
        arm = make_arm_driver(
            args.driver,
            args.port,
            args.arm_config,
            cfg.layout,
            cfg.sim_arm,
            t0=node.clock.now_ns() * NS,
        )
        arm.connect()
    except (ValueError, OSError, ConnectionError) as exc:
        node.close()
        return fail("nod actuation", exc)
    ActuationService(node, cfg, arm, safety, latch_file)
    node.on_forced_exit(arm.hold)  # if a signal's clean stop hangs: hold the arm, then exit
    try:
        node.run()
    finally:
        arm.hold()
        arm.disconnect()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
