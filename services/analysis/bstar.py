"""The bias threshold b* = u_r + margin, derived from a requirement instead of tuned.

Requirement (consensus trials, SPEC §3): when the participant heads straight for the option O,
the robot must be on O's side — its end effector nearer O's box — by the time the participant
presses, so that Algorithm 2's "press the nearest buzzer" gives consensus. The paper's b* = u_r
never gets there (z_r → 0⁻, b_r → u_r asymptotically); a margin above u_r sets how fast the
robot turns.

`agreement_time(margin, reach_s)` runs the pieces that run on the rig — the default observer
on a jittered minimum-jerk reach toward O, the decision model (eq 1 + eq 6), Algorithm 2 and
the simulated arm — and returns when the arm's nearest box becomes O's for good (s after "go").
`derive_margin(press_s)` is the smallest margin whose agreement comes before a press `press_s`
after "go" on every seed — the fastest press the requirement must cover (e.g. the cohort's
10th percentile).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from services.analysis.observer_eval import HAND_RADIUS, HEIGHT, WIDTH
from services.model.arm import SimArm
from services.model.decision import DecisionModel
from services.model.geometry import HAND_TEMPLATE, Colour, TableLayout
from services.model.params import NodConfig
from services.model.robot import RobotTrial

REACTION_S = 0.3  # from "go" to the hand's first movement


@dataclass(frozen=True)
class Agreement:
    """When the robot ends on O's side, for one margin and one reach."""

    margin: float
    reach_s: float  # duration of the hand's reach (after the reaction time)
    agree_s: float  # from "go" to the moment the arm's nearest box is O's for good (inf: never)
    press_s: float  # from "go" to the human's press (reaction + reach)

    @property
    def in_time(self) -> bool:
        """Whether the robot is on O's side when the human presses."""
        return self.agree_s <= self.press_s


def agreement_time(
    margin: float,
    reach_s: float,
    option: Colour = "red",
    cfg: NodConfig | None = None,
    hz: float = 30.0,
    jitter_px: float = 2.0,
    seed: int = 0,
) -> Agreement:
    """Run one consensus trial with a human heading straight for O; see the module doc."""
    base = cfg or NodConfig()
    bias = replace(base.decision.bias, b_star=None, b_star_margin=margin)
    params = replace(base.decision, bias=bias)
    layout: TableLayout = base.layout
    model = DecisionModel(params, layout)
    model.reset("consensus", option)
    robot = RobotTrial(layout, base.behaviour, base.debounce, base.protocol.trial_timeout_s)
    arm = SimArm(layout, base.sim_arm, t0=0.0)
    arm.connect()
    robot.setup(1)
    robot.go(0.0)
    rng = np.random.default_rng(seed)
    start, goal = np.array((0.5, 0.85)), np.array(layout.box(option).center)
    scale = np.array([1.0 / WIDTH, 1.0 / HEIGHT])
    press_s = REACTION_S + reach_s
    agree = math.inf
    t, dt = 0.0, 1.0 / hz
    while t < press_s + 3.0:
        t += dt
        u = min(1.0, max(0.0, (t - REACTION_S) / reach_s))
        centre = start + (goal - start) * (u**3 * (10 - 15 * u + 6 * u * u))
        pts = centre + HAND_TEMPLATE * HAND_RADIUS + rng.normal(0, jitter_px, 2) * scale
        out = model.on_hand(round(t * 1e9), [(float(x), float(y)) for x, y in pts])
        state = arm.state(t)
        cmd = robot.step(t, out.z_r, state.ee)  # no see_hand: it keeps going past the press
        if cmd is not None:
            arm.send(cmd)
        on_o = layout.nearest(arm.state(t).ee) == option
        agree = min(agree, t) if on_o else math.inf
    return Agreement(margin, reach_s, agree, press_s)


def derive_margin(
    press_s: float,
    cfg: NodConfig | None = None,
    seeds: int = 5,
    step: float = 0.1,
    top: float = 4.0,
) -> tuple[float, list[Agreement]]:
    """The smallest margin (on a `step` grid) whose robot agrees before a press at `press_s`.

    Checked for both options and `seeds` jitter draws; raises ValueError when even `top`
    is too slow (the press comes before any robot could turn).
    """
    reach_s = press_s - REACTION_S
    if reach_s <= 0:
        raise ValueError(f"a press {press_s} s after go leaves no time to reach")
    base = cfg or NodConfig()
    cap = base.decision.bias.b_max - base.decision.pair.robot.u
    margins = [round(m * step, 6) for m in range(int(min(top, cap) / step) + 1)]
    for margin in margins:
        runs = [
            agreement_time(margin, reach_s, option, base, seed=seed)
            for option in ("red", "blue")
            for seed in range(seeds)
        ]
        if all(r.in_time for r in runs):
            return margin, runs
    raise ValueError(
        f"no margin up to {margins[-1]} lets the robot agree before a press {press_s} s after "
        "go: the requirement is faster than the arm can turn"
    )
