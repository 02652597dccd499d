"""`nod actuation --options N`: Algorithm 2 over N boxes driving the simulated arm.

`services.actuation.service` over a table of N_o boxes: z_r vectors (`options/z_r`) and hand
poses in, `OptionsRobotTrial` (Algorithm 2 with the dissensus tie rule) deciding, an
`OptionsSimArm` with one pose per box moving. The same safety gate: the watchdog holds the arm
while z_r or the hand is stale, a needed service's liveliness is lost (the conductor's during a
trial) or an e-stop is engaged (`watch_safety_inputs`: the latch file, `safety/estop` and
`safety/release`). The arm's state goes out on `options/arm_state` at 50 Hz (and its safety
state on the paper's `actuation/state`, which acknowledges an e-stop) and the robot's press
once per trial on `options/press`. Only the simulated arm: no real arm is calibrated
for N poses yet.
"""

from __future__ import annotations

import logging

import numpy as np

from services.core import messages as m
from services.core import options_messages as om
from services.core.node import Node
from services.core.options_messages import check_count, same_count, values_for
from services.model.arm import OptionsSimArm
from services.model.behaviour import OptionsCommand
from services.model.geometry import OptionsLayout
from services.model.params import NodConfig
from services.model.robot import OptionsRobotTrial
from services.model.safety import SafetyParams, Watchdog
from services.safety.latch_file import LatchFile
from services.safety.wiring import watch_safety_inputs

log = logging.getLogger("nod.actuation")
NS = 1e-9


class OptionsActuationService:
    """Wires Algorithm 2 over N boxes, the sim arm and the safety watchdog to the rig's keys."""

    def __init__(
        self,
        node: Node,
        cfg: NodConfig,
        layout: OptionsLayout,
        safety: SafetyParams,
        latch_file: LatchFile | None,
    ) -> None:
        self.node = node
        self.n = layout.n_options
        self.layout = layout
        self.arm = OptionsSimArm(layout, cfg.sim_arm, t0=node.clock.now_ns() * NS)
        self.arm.connect()
        self.robot = OptionsRobotTrial(
            layout, cfg.behaviour, cfg.debounce, cfg.protocol.trial_timeout_s
        )
        self.watchdog = Watchdog(safety, ("z_r", "hand"))
        self.safe_stop = True  # until the gate has judged its inputs once
        self.safety_reason = "starting"
        self.last_cmd: OptionsCommand | None = None
        self._t = node.clock.now_ns() * NS  # the rig clock, never a message's stamp, monotone
        self.pub_state = node.publisher("options/arm_state")
        # The device's safety state on the paper's key too (no box there: target none), so the
        # e-stop's acknowledgement, `nod estop`, `nod status` and the recorders work unchanged.
        self.pub_device = node.publisher("actuation/state")
        self.pub_press = node.publisher("options/press")
        node.subscribe("options/z_r", self.on_z_r)
        node.subscribe("vision/hand", self.on_hand)
        node.subscribe("options/layout", self.on_layout)
        node.subscribe("options/trial", self.on_trial)
        watch_safety_inputs(
            node, self.watchdog, self.tick, latch_file, also_watch=("experiment",)
        )
        node.every(0.02, self.tick)

    def on_z_r(self, msg: om.OptionVector) -> None:
        """A new robot opinion vector: one Algorithm 2 step (if fresh by the watchdog's rule)."""
        z_r = values_for(msg, self.n)
        if self.node.feed_watchdog(self.watchdog, "z_r", msg.t_ns):
            self._step(z_r)

    def on_hand(self, pose: m.HandPose) -> None:
        """Watch for the human's press: any landmark inside a box."""
        if self.node.feed_watchdog(self.watchdog, "hand", pose.t_ns) and pose.detected:
            self.robot.see_hand(pose.landmarks)

    def on_layout(self, msg: om.OptionsLayoutMsg) -> None:
        """The boxes the sim publishes (take effect next trial; the arm's poses with them)."""
        self.layout = same_count(msg.layout(), self.n)

    def on_trial(self, ev: om.OptionsTrialEvent) -> None:
        """Setup: home and reset; go: start Algorithm 2; end: the trial's choice is over."""
        check_count(ev, self.n)
        if ev.phase == "setup":
            self.robot.setup(ev.trial, self.layout)
            self.arm.layout = self.layout
            self.watchdog.require("experiment", True)
            self.arm.state(self._now())
            if not self.safe_stop:
                self._send(self.arm.home())
        elif ev.phase == "go" and ev.trial == self.robot.trial:
            self._apply(self.robot.go(self._now()))
        elif ev.phase == "interrupted" and ev.trial == self.robot.trial:
            self.robot.interrupted()
            self.watchdog.require("experiment", False)
        elif ev.phase in ("end", "abort", "session_end"):
            self.watchdog.require("experiment", False)

    def _now(self) -> float:
        self._t = max(self._t, self.node.clock.now_ns() * NS)
        return self._t

    def _step(self, z_r: np.ndarray | None) -> None:
        if not self.robot.running:
            return
        t = self._now()
        cmd = self.robot.step(t, z_r, self.arm.state(t).ee)
        if cmd is not None:
            self._apply(cmd)

    def _apply(self, cmd: OptionsCommand) -> None:
        """Send the behaviour's command unless the safety gate holds the arm (changes only)."""
        last = self.last_cmd
        if self.safe_stop or (last is not None and (cmd.action, cmd.target) == (
                last.action, last.target)):
            return
        self._send(self.arm.send(cmd))

    def _send(self, applied: OptionsCommand) -> None:
        self.last_cmd = applied
        if applied.action != "idle":
            log.debug("arm: %s %s (%s)", applied.action, applied.target, applied.reason)

    def tick(self, now_ns: int) -> None:
        """Periodic: safety gate, Algorithm 2's timers, the arm's state and the robot's press."""
        status = self.watchdog.check(self.node.arrival_ns())
        if status.safe_stop and not self.safe_stop:
            log.warning("SAFE STOP: %s", status.reason)
            self._send(self.arm.hold())
        elif not status.safe_stop and self.safe_stop:
            log.info("safety clear: resuming")
            self.last_cmd = None
            if not self.robot.running and self.robot.trial:
                self._send(self.arm.home())
        self.safe_stop, self.safety_reason = status.safe_stop, status.reason
        if not self.safe_stop:
            self._step(None)
        state = self.arm.state(self._now())
        if state.pressed is not None and self.robot.arm_pressed(state.pressed):
            self.pub_press.put(n_options=self.n, option=state.pressed, trial=self.robot.trial)
            log.info("trial %d: robot pressed box %d", self.robot.trial, state.pressed)
        self.pub_state.put(
            n_options=self.n, ee=state.ee, phase=self.robot.machine.phase, moving=state.moving,
            target=state.target, safe_stop=self.safe_stop,
            safety_reason=self.safety_reason[:400], trial=self.robot.trial,
        )
        self.pub_device.put(
            ee=state.ee, phase=self.robot.machine.phase, moving=state.moving, target=None,
            safe_stop=self.safe_stop, safety_reason=self.safety_reason[:400],
            fault=(state.fault or "")[:400], estop=self.watchdog.estopped,
            estop_id=self.watchdog.estop_id, trial=self.robot.trial,
        )
