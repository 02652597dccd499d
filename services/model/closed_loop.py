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

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from services.model.arm import SimArm
from services.model.decision import DecisionModel
from services.model.geometry import Colour, Point, TableLayout, colour_sign
from services.model.judge import TrialJudge
from services.model.outcome import TrialJudgement
from services.model.params import NodConfig
from services.model.participant import Participant, jittered
from services.model.protocol import Cue, SessionProtocol
from services.model.replayed_hand import Pose, ReplayedHand
from services.model.robot import RobotTrial


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
    interrupted: bool = False  # broken by a safe stop and not repeated: never scored
    attempts: int = 1  # starts of this trial, the interrupted ones included


def centre(pts: np.ndarray) -> Point:
    """The mean (x, y) of landmarks (n × 2): `pts[:, k].mean()` bit for bit, 5× quicker.

    NumPy's mean of a float array is its `add.reduce` (the same pairwise summation) divided by
    the count; calling both directly skips `mean`'s generic wrapper, ~10 µs a call.
    """
    n = len(pts)
    return float(_SUM(pts[:, 0])) / n, float(_SUM(pts[:, 1])) / n


_SUM = np.add.reduce


def box_bounds(layout: TableLayout) -> list[tuple[float, float, float, float]]:
    """(x1, x2, y1, y2) of each buzzer box: a pose whose landmarks all lie outside presses none."""
    return [(b.x1, b.x2, b.y1, b.y2) for b in (layout.red, layout.blue)]


class _Loop:
    """One participant's session: the protocol's cues dispatched to the loop's parts."""

    def __init__(
        self,
        cfg: NodConfig,
        seed: int,
        cohort: bool,
        clicks: int | None,
        record: bool = False,
        hand: ReplayedHand | None = None,
    ) -> None:
        rng = np.random.default_rng(seed)
        params = jittered(cfg.participant, rng) if cohort else cfg.participant
        self.cfg = cfg
        self.clicks = clicks
        self.person: Participant | ReplayedHand = (
            hand
            if hand is not None
            else Participant(params, cfg.layout, seed=int(rng.integers(2**31)))
        )
        self.model = DecisionModel(cfg.decision, cfg.layout)
        self.robot = RobotTrial(
            cfg.layout, cfg.behaviour, cfg.debounce, cfg.protocol.trial_timeout_s
        )
        self.arm = SimArm(cfg.layout, cfg.sim_arm, t0=0.0)
        self._boxes = box_bounds(cfg.layout)
        self.arm.connect()
        self.protocol = SessionProtocol(cfg.protocol)
        self.judge: TrialJudge | None = None  # from "go" to the trial's verdict
        self.t_go = 0.0
        self.record = record
        self.samples: list[LoopSample] = []
        self.results: list[OfflineTrial] = []

    @property
    def human(self) -> Colour | None:
        """The human's press this trial (the judge's, the same one the robot sees)."""
        return self.judge.human if self.judge is not None else None

    def on_cues(self, t: float, cues: list[Cue]) -> None:
        while cues:
            cue = cues.pop(0)
            spec = cue.trial
            if cue.kind == "gaze" and not cue.gesture and cue.gaze is not None:
                self.person.see_gaze(cue.gaze.yaw)
            elif cue.kind == "setup" and spec is not None:
                self.model.reset(spec.mode, spec.consensus_option)
                self.robot.setup(spec.index)
                self.arm.state(t)
                self.arm.home()
                self.person.new_trial(spec.option)
                self.judge = None
                self.samples = []
            elif cue.kind == "go" and spec is not None:
                self.model.reset(spec.mode, spec.consensus_option)
                self.robot.go(t)
                self.person.go(t)
                self.judge = TrialJudge(self.cfg, self.cfg.layout, spec.mode)
                self.t_go = t
            elif cue.kind == "end" and spec is not None:
                self._judge(t, spec.index, spec.mode, spec.option)
                cues.extend(self.protocol.judged(t))
            elif cue.kind == "interrupted" and spec is not None:
                self._interrupted(t, spec.index, spec.mode, spec.option)

    def _judge(self, t: float, index: int, mode: str, option: Colour | None) -> None:
        robot = self.robot.pressed
        self.person.trial_ended(robot)
        assert self.judge is not None  # set at "go", which precedes every "end"
        j = self.judge.verdict(self.protocol.end, robot, self.clicks)
        t_press = self.judge.t_press
        press_s = None if t_press is None or j.human is None else t_press - self.t_go
        self._keep(t, index, mode, option, j, press_s, tuple(self.samples))

    def _interrupted(self, t: float, index: int, mode: str, option: Colour | None) -> None:
        """A safe stop broke the trial: void it, and keep it if it is not repeated.

        The conductor's rule: after `max_attempts`, stored interrupted and never scored.
        """
        self.robot.interrupted()
        self.arm.hold()
        self.judge = None
        proto = self.cfg.protocol
        if not proto.repeat_interrupted or self.protocol.attempt >= proto.max_attempts:
            self._keep(t, index, mode, option, TrialJudge.void(), None, (), interrupted=True)

    def _keep(
        self,
        t: float,
        index: int,
        mode: str,
        option: Colour | None,
        j: TrialJudgement,
        press_s: float | None,
        samples: tuple[LoopSample, ...],
        interrupted: bool = False,
    ) -> None:
        """Store the trial ending at t with judgement j, as the conductor stores it."""
        self.results.append(
            OfflineTrial(
                index, mode, option, j.human, j.robot, j.outcome, j.switches, j.violations,
                j.score, t - self.t_go, press_s, samples, interrupted=interrupted,
                attempts=self.protocol.attempt,
            )
        )

    def frame(self, t: float) -> None:
        """One camera frame: the person moves, decision reads the pose, actuation steps."""
        self.person.advance(t)
        pts = self.person.landmarks()
        landmarks: list[Point] = list(map(tuple, pts.tolist()))  # the same floats, 10× quicker
        out = self.model.on_hand(int(round(t * 1e9)), landmarks)
        judge = self.judge
        center: Point | None = None  # the landmarks' mean, computed once when needed
        # Whether a landmark can be in a box: judge and robot test every landmark against both
        # boxes (`TableLayout.pressed`) and change nothing when none is; a hand whose bounding
        # box meets neither box cannot press, so neither test needs to run.
        xs, ys = pts.T.tolist()
        x_lo, x_hi, y_lo, y_hi = min(xs), max(xs), min(ys), max(ys)
        reach = any(
            x_lo <= x2 and x1 <= x_hi and y_lo <= y2 and y1 <= y_hi
            for x1, x2, y1, y2 in self._boxes
        )
        if judge is not None and judge.human is None:
            center = centre(pts)
            judge.observe(out.z_hat, center, t)
            if reach:
                judge.see_hand(landmarks, t)
        if reach:
            self.robot.see_hand(landmarks)
        state = self.arm.state(t)
        cmd = self.robot.step(t, out.z_r, state.ee)
        if cmd is not None:
            self.arm.send(cmd)
            state = self.arm.state(t)
        heading = colour_sign(state.target) if state.target and state.moving else 0
        self.person.see_robot(t, heading)
        if self.record and judge is not None:
            cx, cy = center or centre(pts)
            self.samples.append(
                LoopSample(
                    round(t * 1e9),
                    cx,
                    cy,
                    out.z_hat,
                    out.z_r,
                    out.b_r,
                    *state.ee,
                    out.observation.theta,
                    out.observation.distance,
                )
            )
        if state.pressed is not None:
            self.robot.arm_pressed(state.pressed)


def run_offline_session(
    cfg: NodConfig,
    seed: int,
    rate_hz: float = 30.0,
    cohort: bool = False,
    clicks: int = 10,
    record: bool = False,
    breaks: Mapping[tuple[int, int], float] | None = None,
    safe_again_s: float = 1.0,
    hands: Mapping[int, Sequence[Pose]] | None = None,
) -> list[OfflineTrial]:
    """Simulate one participant's whole session; return each trial's outcome (and samples).

    `breaks` injects safety interruptions, as a rig's safe stops: (trial, attempt) → seconds
    after that attempt's setup at which a safe stop breaks it. The session then pauses, as the
    conductor's does, until the rig has been safe for `safe_again_s` (the stop's own length and
    the conductor's settling time), and repeats the trial or moves on as the protocol says.

    `hands` replaces the simulated participant with a recorded hand: per trial, its poses timed
    from that trial's "go" (`services.model.replayed_hand`; `services.recording.reaches` reads
    them from a recording).
    """
    hand = ReplayedHand(hands) if hands is not None else None
    loop = _Loop(cfg, seed, cohort, clicks, record, hand)
    breaks = dict(breaks or {})
    dt = 1.0 / rate_hz
    t = 0.0
    t_setup = 0.0
    broken_at: float | None = None
    loop.on_cues(t, loop.protocol.start(t))
    while not loop.protocol.done:
        t += dt
        loop.frame(t)
        proto = loop.protocol
        if proto.waiting_for_operator:  # a gated protocol: the simulated operator starts at once
            cues = proto.open_gate(t)
        elif proto.phase == "paused":
            assert broken_at is not None
            cues = proto.resume(t) if t - broken_at >= safe_again_s else []
        elif (
            proto.running_trial
            and proto.trial is not None
            and t - t_setup >= breaks.get((proto.trial.index, proto.attempt), math.inf)
        ):
            broken_at = t
            cues = proto.interrupt(t, "simulated safe stop")
        else:
            cues = proto.advance(
                t,
                human_pressed=loop.human is not None,
                robot_pressed=loop.robot.pressed is not None,
            )
        if any(c.kind == "setup" for c in cues):
            t_setup = t
        loop.on_cues(t, cues)
    return loop.results
