"""The closed loop in one process, without Zenoh: for cohorts, power analysis, tuning and tests.

It drives the same `SessionProtocol` as the conductor and reacts to its cues the way the
services do on the fabric — decision and actuation reset at "setup", start at "go"; the
participant reads the gaze, waits for "go" and watches the arm — with the same pure parts:
`Participant`, `DecisionModel`, `RobotBehaviour`, `SimArm`, `OutcomeTracker`, `judge_trial`.
Everything advances in lock step at camera rate, so a seed gives one exact session. A
distributed session gives the same kind of outcomes, not bit-identical ones: message timing
differs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from services.model.arm import SimArm
from services.model.behaviour import RobotBehaviour
from services.model.decision import DecisionModel
from services.model.geometry import Colour, colour_sign
from services.model.outcome import OutcomeTracker, judge_trial
from services.model.params import NodConfig
from services.model.participant import Participant, jittered
from services.model.protocol import Cue, SessionProtocol


class LoopSample(NamedTuple):
    """One camera frame of a simulated trial: the hand, the decision's outputs, the arm."""

    t_ns: int
    hand_x: float
    hand_y: float
    z_h: float
    z_r: float
    b_r: float
    ee_x: float
    ee_y: float
    theta: float | None  # eq 7's θ when this frame set ẑ_h
    distance: float | None  # eq 7's d when this frame set ẑ_h


@dataclass(frozen=True, slots=True)
class OfflineTrial:
    """The result of one simulated trial."""

    trial: int
    mode: str
    option: Colour | None
    human: Colour | None
    robot: Colour | None
    outcome: str | None
    switches: int
    violations: int
    score: int
    duration_s: float  # from "go" to the end of the trial
    press_s: float | None = None  # from "go" to the human's press (None: never pressed)
    samples: tuple[LoopSample, ...] = ()  # every frame from "go" to the end (when recorded)


class _Loop:
    """One participant's session: the protocol's cues dispatched to the loop's parts."""

    def __init__(
        self, cfg: NodConfig, seed: int, cohort: bool, clicks: int | None, record: bool = False
    ) -> None:
        rng = np.random.default_rng(seed)
        params = jittered(cfg.participant, rng) if cohort else cfg.participant
        self.cfg = cfg
        self.clicks = clicks
        self.person = Participant(params, cfg.layout, seed=int(rng.integers(2**31)))
        self.model = DecisionModel(cfg.decision, cfg.layout)
        self.behaviour = RobotBehaviour(cfg.layout, cfg.behaviour, cfg.debounce)
        self.arm = SimArm(cfg.layout, cfg.sim_arm, t0=0.0)
        self.arm.connect()
        self.protocol = SessionProtocol(cfg.protocol)
        self.tracker: OutcomeTracker | None = None  # recording from "go" to the human's press
        self.human: Colour | None = None
        self.robot: Colour | None = None
        self.t_go = 0.0
        self.t_press: float | None = None
        self.record = record
        self.samples: list[LoopSample] = []
        self.results: list[OfflineTrial] = []

    def on_cues(self, t: float, cues: list[Cue]) -> None:
        while cues:
            cue = cues.pop(0)
            spec = cue.trial
            if cue.kind == "gaze" and not cue.gesture and cue.gaze is not None:
                self.person.see_gaze(cue.gaze.yaw)
            elif cue.kind == "setup" and spec is not None:
                self.model.reset(spec.mode, spec.consensus_option)
                self.behaviour.reset()
                self.arm.state(t)
                self.arm.home()
                self.person.new_trial(spec.option)
                self.tracker, self.human, self.robot, self.t_press = None, None, None, None
                self.samples = []
            elif cue.kind == "go" and spec is not None:
                self.model.reset(spec.mode, spec.consensus_option)
                self.behaviour.start(t, self.cfg.protocol.trial_timeout_s)
                self.person.go(t)
                self.tracker = OutcomeTracker(
                    self.cfg.debounce,
                    self.cfg.layout.commit,
                    self.cfg.decision.observer.switch_dead_band,
                )
                self.t_go = t
            elif cue.kind == "end" and spec is not None:
                self._judge(t, spec.index, spec.mode, spec.option)
                cues.extend(self.protocol.judged(t))

    def _judge(self, t: float, index: int, mode: str, option: Colour | None) -> None:
        self.person.trial_ended(self.robot)
        assert self.tracker is not None  # set at "go", which precedes every "end"
        end = self.protocol.end
        human = self.human if end is None else end.counted_press(self.human)
        target = self.cfg.protocol.target_clicks
        j = judge_trial(self.tracker, human, self.robot, self.clicks, target)
        self.results.append(
            OfflineTrial(
                index, mode, option, j.human, j.robot, j.outcome, j.switches, j.violations,
                j.score, t - self.t_go,
                None if self.t_press is None or human is None else self.t_press - self.t_go,
                tuple(self.samples),
            )
        )

    def frame(self, t: float) -> None:
        """One camera frame: the person moves, decision reads the pose, actuation steps."""
        self.person.advance(t)
        pts = self.person.landmarks()
        landmarks = [(float(x), float(y)) for x, y in pts]
        out = self.model.on_hand(int(round(t * 1e9)), landmarks)
        if self.tracker is not None and self.human is None:
            center = (float(pts[:, 0].mean()), float(pts[:, 1].mean()))
            self.tracker.add(out.z_hat, center)
            self.human = self.cfg.layout.pressed(landmarks)
            if self.human is not None:
                self.t_press = t
        state = self.arm.state(t)
        if self.behaviour.phase != "idle":
            self.arm.send(self.behaviour.step(t, out.z_r, self.human, state.ee))
            state = self.arm.state(t)
        heading = colour_sign(state.target) if state.target and state.moving else 0
        self.person.see_robot(t, heading)
        if self.record and self.tracker is not None:
            cx, cy = float(pts[:, 0].mean()), float(pts[:, 1].mean())
            self.samples.append(
                LoopSample(
                    round(t * 1e9), cx, cy, out.z_hat, out.z_r, out.b_r, *state.ee,
                    out.observation.theta, out.observation.distance,
                )
            )
        if state.pressed is not None and self.robot is None and self.behaviour.t_go is not None:
            self.behaviour.complete()
            self.robot = state.pressed


def run_offline_session(
    cfg: NodConfig,
    seed: int,
    rate_hz: float = 30.0,
    cohort: bool = False,
    clicks: int = 10,
    record: bool = False,
) -> list[OfflineTrial]:
    """Simulate one participant's whole session; return each trial's outcome (and samples)."""
    loop = _Loop(cfg, seed, cohort, clicks, record)
    dt = 1.0 / rate_hz
    t = 0.0
    loop.on_cues(t, loop.protocol.start(t))
    while not loop.protocol.done:
        t += dt
        loop.frame(t)
        loop.on_cues(
            t,
            loop.protocol.advance(
                t, human_pressed=loop.human is not None, robot_pressed=loop.robot is not None
            ),
        )
    return loop.results
