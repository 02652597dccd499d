"""A synthetic participant over N_o boxes: eq 2 as an N_o-vector steering a hand to one box.

`services.model.participant`'s person (the same `ParticipantParams`) on a table of N_o boxes:

- the opinion z_h (an N_o-vector, Σ = 0) follows eq 2 over options (`human_rate`, on floats),
  ż_h = F(z_h, r̂) − mean, with the robot's perceived heading r̂ = option_vector(box the arm
  heads for), seen `perception_delay_s` late, and γ_h > 0 (the person wants to match);
- the bias b_h = preference + gaze, each along an option's `option_vector`: a preference for a
  random box with a magnitude drawn as the two-option person's, and the gaze cue's pull toward
  the box the eyes look at (`gaze.read_gaze`), gaze_gain · strength · trust. With two
  boxes these are the two-option person's b_h = ±preference ± pull;
- after the reaction time the hand heads for the box of z_h's leading option, its speed scaled
  by conviction (the lead of that option over the runner-up, as |z_h| is with two boxes); a
  change of box is a switch, at most `max_switches`, none past the commit line for a person who
  keeps the rules; trust grows after a consensus trial in which following the gaze paid off.

Not modelled here (two-option only): the strategic late switch (`late_switch_*`) and
`gaze_over_robot`. Pure: time is an argument, randomness a seeded numpy Generator.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from services.model.dynamics import (
    OptionsParams,
    PairParams,
    float_rates,
    leading_option,
    option_vector,
)
from services.model.gaze import GazeCommand, read_gaze
from services.model.geometry import HAND_TEMPLATE, CommitLine, OptionsLayout
from services.model.participant import ParticipantParams


class OptionsParticipant:
    """One simulated person over a session of trials on a table of N_o boxes."""

    def __init__(
        self, params: ParticipantParams, layout: OptionsLayout, seed: int,
        commit: CommitLine | None = None,
    ) -> None:
        """A person for `layout` (`commit`: the rule's line; default the layout's)."""
        self.p = params
        self.layout = layout
        self.commit = commit if commit is not None else layout.commit
        self.n = layout.n_options
        self.dynamics = OptionsParams(PairParams(human=params.agent), n_options=self.n)
        self.rng = np.random.default_rng(seed)
        self.trust = params.trust0
        self._reach = float(np.abs(HAND_TEMPLATE).max()) * params.hand_radius
        self._gaze = GazeCommand()
        self._robot_seen: deque[tuple[float, int | None]] = deque()
        self.new_trial(None)

    # -- protocol events -------------------------------------------------------------------

    def see_gaze(self, gaze: GazeCommand) -> None:
        """The eyes' current gaze cue (not the attention gesture's poses)."""
        self._gaze = gaze

    def new_trial(self, option: int | None) -> None:
        """Prepare for a trial ("setup", `option` its O or None): draw today's preference."""
        strength = abs(self.rng.normal(self.p.preference_mean, self.p.preference_sd))
        self._preference = strength * option_vector(int(self.rng.integers(self.n)), self.n)
        self.b_h = self._preference.copy()
        self.z_h = np.zeros(self.n)
        self._x, self._y = self.p.start
        self._vx = self._vy = 0.0
        self.t = 0.0
        self.t_go: float | None = None
        self.pressed: int | None = None
        self.switches = 0
        self._heading: int | None = None
        self._obeys_commit = bool(self.rng.random() >= self.p.rule_breaking)
        allowed = option is not None or self.rng.random() < self.p.control_switch_prob
        self._max_switches = self.p.max_switches if allowed else 0
        self._robot_seen.clear()
        self._last_seen: int | None = None
        self._cue: int | None = None

    def go(self, t: float) -> None:
        """The countdown said "go": the bias is today's preference plus the gaze cue's pull."""
        cue, strength = read_gaze(self.layout, self._gaze)
        self._cue = cue
        self.b_h = self._preference.copy()
        if cue is not None:
            self.b_h += self.p.gaze_gain * strength * self.trust * option_vector(cue, self.n)
        self.t_go = t
        self.t = max(self.t, t)

    def trial_ended(self, robot: int | None) -> None:
        """Learn from the trial: following the gaze and agreeing with the robot builds trust."""
        if self._cue is not None and robot is not None and self.pressed is not None:
            followed = self.pressed == self._cue
            if followed and self.pressed == robot:
                self.trust += self.p.trust_step
            elif followed:
                self.trust = max(0.0, self.trust - self.p.trust_step)

    def see_robot(self, t: float, heading: int | None) -> None:
        """What the arm is doing now: the box it heads for, None when still."""
        self._robot_seen.append((t, heading))

    # -- dynamics --------------------------------------------------------------------------

    def _robot_perceived(self) -> np.ndarray:
        cutoff = self.t - self.p.perception_delay_s
        while self._robot_seen and self._robot_seen[0][0] <= cutoff:
            self._last_seen = self._robot_seen.popleft()[1]
        seen = self._last_seen
        return np.zeros(self.n) if seen is None else option_vector(seen, self.n)

    def advance(self, t: float, dt: float = 0.002) -> None:
        """Integrate opinion (eq 2, RK4 with r̂ held) and hand motion up to time t."""
        if self.t_go is None or self.pressed is not None:
            self.t = max(self.t, t)
            return
        while self.t < t - 1e-12:
            h = min(dt, t - self.t)
            self._step(h)
            self.t += h

    def _step(self, h: float) -> None:
        a = self.p.agent
        social = [self.dynamics.pair.a_hr * float(r) for r in self._robot_perceived()]
        z, b = [float(x) for x in self.z_h], [float(x) for x in self.b_h]
        # eq 2 over options (`options.human_rate`, on floats: this runs every 2 ms simulated)
        k1 = float_rates(z, social, b, a.d, a.u, a.alpha, a.gamma)
        k2 = float_rates([x + 0.5 * h * k for x, k in zip(z, k1, strict=True)], social, b,
                  a.d, a.u, a.alpha, a.gamma)
        k3 = float_rates([x + 0.5 * h * k for x, k in zip(z, k2, strict=True)], social, b,
                  a.d, a.u, a.alpha, a.gamma)
        k4 = float_rates([x + h * k for x, k in zip(z, k3, strict=True)], social, b,
                  a.d, a.u, a.alpha, a.gamma)
        self.z_h = np.array([x + (h / 6.0) * (p1 + 2.0 * (p2 + p3) + p4)
                             for x, p1, p2, p3, p4 in zip(z, k1, k2, k3, k4, strict=True)])
        assert self.t_go is not None  # `advance` steps only after "go"
        if self.t < self.t_go + self.p.reaction_s:
            return
        committed = self._heading is not None and (
            self.switches >= self._max_switches
            or (self._obeys_commit and self.commit.crossed((self._x, self._y)))
        )
        wanted = leading_option(self.z_h)
        if wanted is not None and self._heading is None:
            self._heading = wanted
        elif wanted is not None and wanted != self._heading and not committed:
            self._heading = wanted
            self.switches += 1
        if self._heading is None:
            return
        self._move(h, 1.0 if committed else self._conviction())
        self.pressed = self._press_test()

    def _conviction(self) -> float:
        """The lead of the leading option over the runner-up, as |z_h| with two boxes."""
        top_two = np.sort(self.z_h)[-2:]
        lead = 0.5 * float(top_two[1] - top_two[0])
        return min(1.0, max(self.p.min_conviction, lead / self.p.full_conviction))

    def _move(self, h: float, conviction: float) -> None:
        assert self._heading is not None
        tx, ty = self.layout.boxes[self._heading].center
        dx, dy = tx - self._x, ty - self._y
        dist = math.hypot(dx, dy)
        gain = self.p.speed * conviction / max(dist, 1e-9)
        ax, ay = dx * gain - self._vx, dy * gain - self._vy
        dv = math.hypot(ax, ay)
        max_dv = self.p.accel * h
        if dv > max_dv:
            ax, ay = ax * max_dv / dv, ay * max_dv / dv
        self._vx, self._vy = self._vx + ax, self._vy + ay
        self._x, self._y = self._x + self._vx * h, self._y + self._vy * h

    def _press_test(self) -> int | None:
        """A landmark of the (noise-free) hand inside a box; cheap when far from every box."""
        reach = self._reach
        for box in self.layout.boxes:
            if (box.x1 - reach <= self._x <= box.x2 + reach
                    and box.y1 - reach <= self._y <= box.y2 + reach):
                pts = [(float(x), float(y)) for x, y in self.landmarks(noise=False)]
                return self.layout.pressed(pts)
        return None

    @property
    def pos(self) -> np.ndarray:
        """The hand centre (x, y)."""
        return np.array((self._x, self._y))

    @property
    def heading(self) -> int | None:
        """The box the hand heads for (None before it moves)."""
        return self._heading

    # -- what the camera sees ---------------------------------------------------------------

    def landmarks(self, noise: bool = True) -> np.ndarray:
        """21 landmarks (x, y) around the hand centre, with camera noise when asked."""
        pts = np.array((self._x, self._y)) + HAND_TEMPLATE * self.p.hand_radius
        if noise:
            common = self.rng.normal(0.0, self.p.common_noise, 2)
            pts = pts + common + self.rng.normal(0.0, self.p.landmark_noise, pts.shape)
        return np.clip(pts, 0.0, 1.0)
