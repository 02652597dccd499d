"""The closed loop in one process, without Zenoh: for tuning, tests and fast what-ifs.

The same pure parts the services wrap — Participant, DecisionModel, RobotBehaviour, SimArm,
OutcomeTracker, score_trial — wired in lock step at camera rate. It shares no code path with the
distributed run but the pure core, which is exactly what makes it a useful cross-check: the
distributed session should produce the same kind of outcomes (not bit-identical ones: message
timing differs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.model.arm import SimArm
from services.model.behaviour import RobotBehaviour
from services.model.decision import DecisionModel
from services.model.geometry import Colour, colour_sign
from services.model.outcome import OutcomeTracker
from services.model.params import NodConfig
from services.model.participant import Participant, jittered
from services.model.scoring import score_trial


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
    duration_s: float


def run_offline_session(
    cfg: NodConfig, seed: int, rate_hz: float = 30.0, cohort: bool = False, clicks: int = 10
) -> list[OfflineTrial]:
    """Simulate one participant's session; return each trial's outcome."""
    rng = np.random.default_rng(seed)
    params = jittered(cfg.participant, rng) if cohort else cfg.participant
    person = Participant(params, cfg.layout, seed=int(rng.integers(2**31)))
    model = DecisionModel(cfg.decision, cfg.layout)
    arm = SimArm(cfg.layout, cfg.sim_arm, t0=0.0)
    arm.connect()
    dt = 1.0 / rate_hz
    t = 0.0
    out: list[OfflineTrial] = []
    for spec in cfg.protocol.trials:
        arm.state(t)
        arm.home()
        t += 2.0  # time to get home and for the participant to see the gaze
        arm.state(t)
        person.advance(t)
        person.new_trial(spec.yaw, spec.option)
        model.reset(spec.mode, spec.option if spec.mode == "consensus" else None)
        behaviour = RobotBehaviour(cfg.layout, cfg.behaviour)
        tracker = OutcomeTracker(cfg.protocol.switch_c_max, cfg.layout.commit)
        t_go = t
        person.go(t_go)
        behaviour.start(t_go)
        human: Colour | None = None
        robot: Colour | None = None
        seq = 0
        while t - t_go < cfg.protocol.trial_timeout_s + 5.0:
            t += dt
            person.advance(t)
            landmarks = [tuple(p) for p in person.landmarks()]
            res = model.on_hand(int(round(t * 1e9)), landmarks)
            seq += 1
            if human is None:
                center = tuple(np.mean(landmarks, axis=0))
                tracker.add(res.z_hat, center)
                human = cfg.layout.pressed(landmarks)
            state = arm.state(t)
            arm.send(behaviour.step(t, res.z_r, human, state.ee))
            state = arm.state(t)
            heading = colour_sign(state.target) if state.target and state.moving else 0
            person.see_robot(t, heading)
            if state.pressed is not None:
                behaviour.complete()
                robot = state.pressed
                break
        person.trial_ended(robot)
        result = tracker.result(human, robot) if robot else None
        score = score_trial(
            result is not None and result.same_buzzer,
            clicks,
            result.violations if result else 0,
            cfg.protocol.target_clicks,
        )
        out.append(
            OfflineTrial(
                trial=spec.index,
                mode=spec.mode,
                option=spec.option,
                human=human,
                robot=robot,
                outcome=result.outcome if (result and human) else None,
                switches=result.switches if result else 0,
                violations=result.violations if result else 0,
                score=score.total,
                duration_s=t - t_go,
            )
        )
    return out
