"""The closed loop over N_o options in one process, without Zenoh (docs/multi-option.md).

`services.model.closed_loop` for a table of N_o boxes: the same `SessionProtocol` clock (its
trials from `OptionsSchedule.timing_specs`, each trial's mode and O looked up in the schedule),
reacted to with the N_o-option parts — `Participant` (the one person), `OptionsDecision`,
`OptionsRobotTrial`, `OptionsSimArm`, `OptionsTrialJudge` — all in lock step at camera rate,
so a seed gives one exact session. The option count selects this loop; two options keep the
paper's `run_offline_session`. Safety interruptions are not injected here.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from services.model.arm import OptionsSimArm
from services.model.decision import OptionsDecision
from services.model.judge import OptionsTrialJudge
from services.model.params import NodConfig
from services.model.participant import Participant, jittered
from services.model.protocol import Cue, SessionProtocol
from services.model.robot import OptionsRobotTrial
from services.model.schedule import Mode, OptionsSchedule


@dataclass(frozen=True, slots=True)
class OptionsOfflineTrial:
    """The result of one simulated N_o-option trial (options by index into the schedule)."""

    trial: int
    mode: Mode
    option: int | None
    human: int | None
    robot: int | None
    outcome: str | None
    switches: int
    violations: int
    score: int
    duration_s: float  # from "go" to the end of the trial
    press_s: float | None  # from "go" to the human's press (None: never pressed)


class _OptionsLoop:
    """One participant's session over N_o boxes: the protocol's cues dispatched to its parts."""

    def __init__(
        self, cfg: NodConfig, schedule: OptionsSchedule, seed: int, cohort: bool, clicks: int
    ) -> None:
        rng = np.random.default_rng(seed)
        self.cfg, self.schedule, self.clicks = cfg, schedule, clicks
        self.layout = cfg.table(schedule.n_options)
        params = jittered(cfg.participant, rng) if cohort else cfg.participant
        self.person = Participant(params, self.layout, int(rng.integers(2**31)))
        self.model = OptionsDecision(self.layout, cfg.decision)
        self.robot = OptionsRobotTrial(
            self.layout, cfg.behaviour, cfg.debounce, cfg.protocol.trial_timeout_s
        )
        self.arm = OptionsSimArm(self.layout, cfg.sim_arm, t0=0.0)
        self.arm.connect()
        proto = replace(cfg.protocol, trials=schedule.timing_specs(self.layout))
        self.protocol = SessionProtocol(proto)
        self.judge: OptionsTrialJudge | None = None
        self.t_go = 0.0
        self.results: list[OptionsOfflineTrial] = []

    def on_cues(self, t: float, cues: list[Cue]) -> None:
        while cues:
            cue = cues.pop(0)
            if cue.trial is None:
                continue
            trial = self.schedule.trial(cue.trial.index)
            if cue.kind == "gaze" and not cue.gesture and cue.gaze is not None:
                self.person.see_gaze(cue.gaze)
            elif cue.kind == "setup":
                self.model.reset(trial.mode, trial.option)
                self.robot.setup(trial.index)
                self.arm.state(t)
                self.arm.home()
                self.person.new_trial(trial.option)
                self.judge = None
            elif cue.kind == "go":
                self.model.reset(trial.mode, trial.option)
                self.robot.go(t)
                self.person.go(t)
                self.judge = OptionsTrialJudge(self.cfg, self.layout, trial.mode)
                self.t_go = t
            elif cue.kind == "end":
                robot = self.robot.pressed
                self.person.trial_ended(robot)
                assert self.judge is not None  # set at "go", which precedes every "end"
                j = self.judge.verdict(self.protocol.end, robot, self.clicks)
                t_press = self.judge.t_press
                self.results.append(OptionsOfflineTrial(
                    trial.index, trial.mode, trial.option, j.human, j.robot, j.outcome,
                    j.switches, j.violations, j.score, t - self.t_go,
                    None if t_press is None or j.human is None else t_press - self.t_go,
                ))
                cues.extend(self.protocol.judged(t))

    def frame(self, t: float) -> None:
        """One camera frame: the person moves, decision reads the pose, the arm steps."""
        self.person.advance(t)
        pts = self.person.landmarks()
        landmarks = [(float(x), float(y)) for x, y in pts]
        out = self.model.on_hand(int(round(t * 1e9)), landmarks)
        judge = self.judge
        if judge is not None and judge.human is None:
            center = (float(pts[:, 0].mean()), float(pts[:, 1].mean()))
            judge.observe(out.z_hat, center, t)
            judge.see_hand(landmarks, t)
        self.robot.see_hand(landmarks)
        state = self.arm.state(t)
        cmd = self.robot.step(t, out.z_r, state.ee)
        if cmd is not None:
            self.arm.send(cmd)
            state = self.arm.state(t)
        self.person.see_robot(t, state.target if state.moving else None)
        if state.pressed is not None:
            self.robot.arm_pressed(state.pressed)


def run_options_session(
    cfg: NodConfig,
    schedule: OptionsSchedule,
    seed: int,
    rate_hz: float = 30.0,
    cohort: bool = False,
    clicks: int = 10,
) -> list[OptionsOfflineTrial]:
    """Simulate one participant's whole N_o-option session; return each trial's outcome."""
    loop = _OptionsLoop(cfg, schedule, seed, cohort, clicks)
    dt = 1.0 / rate_hz
    t = 0.0
    loop.on_cues(t, loop.protocol.start(t))
    while not loop.protocol.done:
        t += dt
        loop.frame(t)
        proto = loop.protocol
        if proto.waiting_for_operator:  # a gated protocol: the simulated operator starts at once
            cues = proto.open_gate(t)
        else:
            cues = proto.advance(
                t, human_pressed=loop.judge is not None and loop.judge.human is not None,
                robot_pressed=loop.robot.pressed is not None,
            )
        loop.on_cues(t, cues)
    return loop.results
