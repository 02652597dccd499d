"""`nod eyes`: gaze commands → per-eye pan/tilt servo targets through a servo driver.

The conductor publishes the gaze on `eyes/cmd` (the attention gesture's poses before trial 4
too, marked `gesture`) and repeats the current one as a keep-alive; the eyes look where the
latest command says. When the gaze goes stale, a needed service's liveliness is lost, or an
e-stop is engaged, the eyes go to neutral and say why.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import sys

from services.core import messages as m
from services.core.cli import fail, service_parser
from services.core.config import load_params, params_hash
from services.core.node import Node, setup_logging
from services.core.priority import raise_priority
from services.core.session import Fabric
from services.eyes.drivers import add_driver_args, make_eyes_driver
from services.eyes.servos import ServoDriver
from services.model.gaze import GazeCommand
from services.model.params import NodConfig
from services.model.safety import SafetyParams, Watchdog
from services.model.servos import SERVO_NAMES, ServoTargets
from services.safety.latch_file import LatchFile, add_state_dir_arg, default_state_dir
from services.safety.wiring import run_device_service, watch_safety_inputs

log = logging.getLogger("nod.eyes")


class EyesService:
    """Wires gaze commands and the watchdog to a servo driver."""

    def __init__(
        self,
        node: Node,
        driver: ServoDriver,
        safety: SafetyParams,
        latch_file: LatchFile | None,
    ) -> None:
        self.node = node
        self.driver = driver
        self.watchdog = Watchdog(safety, ("gaze",))
        self.gaze = GazeCommand()
        self._logged: tuple[int, str, bool] | None = None
        self.applied: ServoTargets = driver.neutral()
        self._last_cmd: GazeCommand | None = GazeCommand()
        self.safe_stop = False
        self.reason = ""
        self.pub_state = node.publisher("eyes/state")
        node.subscribe("eyes/cmd", self.on_gaze)
        watch_safety_inputs(node, self.watchdog, self.tick, latch_file)
        node.every(0.02, self.tick)

    def on_gaze(self, msg: m.GazeMsg) -> None:
        """A gaze command (or its keep-alive): look there now.

        The attention gesture arrives as a sequence of such commands from the conductor's
        protocol (`gesture` marks its poses), so its timing has one home and the eyes only follow.
        """
        if not self.node.feed_watchdog(self.watchdog, "gaze", msg.t_ns):
            return  # stamped outside the skew bound: not a command to follow
        self.gaze = GazeCommand(msg.yaw, msg.pitch)
        what = (msg.trial, msg.level, msg.gesture)
        if what != self._logged:  # a new cue, not a keep-alive
            self._logged = what
            log.info(
                "trial %d: gaze %s yaw=%+.2f pitch=%+.2f%s",
                msg.trial,
                msg.level,
                msg.yaw,
                msg.pitch,
                " (attention gesture)" if msg.gesture else "",
            )
        self.tick(self.node.clock.now_ns())

    def tick(self, now_ns: int) -> None:
        """Apply the current gaze (or neutral when unsafe) and publish the state."""
        poll = getattr(self.driver, "poll", None)  # serial drivers reconnect and re-send here
        if poll is not None:
            poll()
        # A silent or unplugged servo controller is a safety stop: neutral is commanded (it
        # lands once the controller answers again) and the conductor interrupts the trial.
        fault = getattr(self.driver, "fault", None)
        self.watchdog.set_fault(fault)
        status = self.watchdog.check(self.node.arrival_ns())
        if status.safe_stop != self.safe_stop:
            (log.warning if status.safe_stop else log.info)(
                "eyes %s: %s",
                "NEUTRAL (safe stop)" if status.safe_stop else "resume",
                status.reason or "inputs fresh",
            )
        self.safe_stop, self.reason = status.safe_stop, status.reason
        cmd = GazeCommand() if self.safe_stop else self.gaze
        if cmd != self._last_cmd:  # servos hold their target: send changes only
            self.applied = self.driver.look(cmd)
            self._last_cmd = cmd
        if self.applied.clamped:
            log.debug("clamped servos: %s", ", ".join(self.applied.clamped))
        self.pub_state.put(
            angles_deg=self.applied.angles_deg,
            pulses_us=self.applied.pulses_us,
            clamped=self.applied.clamped,
            safe_stop=self.safe_stop,
            safety_reason=self.reason[:400],
            fault=(fault or "")[:400],
            estop=self.watchdog.estopped,
            estop_id=self.watchdog.estop_id,
        )


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod eyes`."""
    p = service_parser(
        "nod eyes",
        "Drive the two servo eyes from gaze commands (Section 5).",
        epilog="Bench tools on the eyes' host (no Zenoh; stop the service first): "
        "`nod eyes point --yaw Y --pitch P …` looks at one gaze, "
        "`nod eyes calibrate --out eyes_trims.toml …` centres the servos (see their --help).",
    )
    add_driver_args(p)
    p.add_argument("--stale-ms", type=float, default=None, help="gaze staleness bound (ms)")
    add_state_dir_arg(p)
    return p


def eyes_safety(cfg: NodConfig, stale_ms: float | None) -> SafetyParams:
    """The eyes' watchdog: the gaze keepalive, plus the conductor's liveliness."""
    base = cfg.safety
    needed = base.require_alive + (() if "experiment" in base.require_alive else ("experiment",))
    return dataclasses.replace(
        base, stale_ms=base.stale_ms if stale_ms is None else stale_ms, require_alive=needed
    )


def main(argv: list[str] | None = None) -> int:
    """Run the eyes service until SIGINT/SIGTERM (`point` and `calibrate` are bench tools)."""
    if argv is None:
        argv = sys.argv[1:]
    if argv[:1] == ["point"]:
        from services.eyes.point import main as point

        return point(argv[1:])
    if argv[:1] == ["calibrate"]:
        from services.eyes.calibrate import main as calibrate

        return calibrate(argv[1:])
    args = build_parser().parse_args(argv)
    setup_logging(args.verbose)
    try:
        cfg = load_params(args.params)
        safety = eyes_safety(cfg, args.stale_ms)
        # Built (not connected) before the session: a bad eyes or trims file fails at once.
        driver = make_eyes_driver(
            args.driver, args.port, args.eyes_config, calibration=cfg.eyes, trims=args.trims
        )
        latch_file = LatchFile(args.state_dir or default_state_dir(), args.rig, "eyes")
        latch_file.check_writable()  # eyes whose e-stop cannot survive a restart do not start
        node = Node("eyes", Fabric.from_args(args), retry_s=math.inf, params_hash=params_hash(cfg))
    except (ValueError, OSError, ConnectionError) as exc:
        return fail("nod eyes", exc)
    log.info("effective config: %s", json.dumps(cfg.summary("eyes", "safety")))
    raise_priority("eyes")  # once its configuration is good: errors stay one line
    try:
        driver.connect()
    except (ValueError, OSError, ConnectionError) as exc:
        node.close()
        return fail("nod eyes", exc)
    if args.trims is not None:
        servos = driver.calibration.servos()
        trims = {s: c.trim_deg for s, c in zip(SERVO_NAMES, servos, strict=True)}
        log.info("servo trims from %s: %s", args.trims, json.dumps(trims))
    EyesService(node, driver, safety, latch_file)
    run_device_service(node, driver)  # the eyes look ahead however the service ends
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
