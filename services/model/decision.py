"""The decision engine: observer (eq 7) → robot opinion (eq 1) with the bias controller (eq 6).

Feed it hand poses with their source timestamps (`on_hand`). Between two poses the robot state
(z_r, b_r) is integrated with fixed-step RK4, holding the previously observed ẑ_h constant
(zero-order hold, SPEC §1); then the new pose updates ẑ_h, which only affects later intervals.
Time comes from the timestamps alone, so a recorded stream replays identically.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

from services.model.bias import BiasParams, beta_for, bias_active, bias_rate, sigma_for
from services.model.dynamics import PairParams, opinion_rate
from services.model.geometry import Colour, Point, TableLayout
from services.model.observer import Observation, ObserverParams
from services.model.observer_robust import make_observer
from services.model.protocol import MODES, Mode


@dataclass(frozen=True)
class DecisionParams:
    """Everything the decision engine needs: dynamics, observer, bias controller, integration."""

    pair: PairParams = field(default_factory=PairParams)  # eq 1 uses the robot's row
    observer: ObserverParams = field(default_factory=ObserverParams)
    bias: BiasParams = field(default_factory=BiasParams)
    dt: float = 0.001  # internal RK4 step (s)
    # A gap between poses longer than this is integrated only up to this bound (s): stale input
    # must not wind up the state.
    max_gap_s: float = 0.5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.dt) and self.dt >= 1e-9):
            raise ValueError(f"DecisionParams.dt must be a finite step >= 1 ns, got {self.dt!r}")
        if not (math.isfinite(self.max_gap_s) and self.max_gap_s > 0):
            raise ValueError(
                f"DecisionParams.max_gap_s must be finite and > 0, got {self.max_gap_s!r}"
            )
        b_star = self.bias.threshold(self.pair.robot.u)
        if b_star > self.bias.b_max:
            raise ValueError(
                f"bias threshold b* = {b_star} exceeds the clamp b_max = {self.bias.b_max}: "
                "raise bias.b_max or lower bias.b_star / bias.b_star_margin"
            )


class DecisionOutput(NamedTuple):
    """The engine's state after one pose (a NamedTuple: built once per camera frame).

    `t_ns` is the time the state refers to: the pose's timestamp, or the previous one when the
    pose was rejected for a timestamp that did not advance.
    """

    t_ns: int
    z_hat: float
    z_r: float
    b_r: float
    observation: Observation
    dissensus: bool  # z_r · ẑ_h < 0


class DecisionModel:
    """Robot opinion z_r and bias b_r driven by observed hand poses (Algorithm 1)."""

    def __init__(self, params: DecisionParams | None = None, layout: TableLayout | None = None):
        self._params = params if params is not None else DecisionParams()
        self._observer = make_observer(self._params.observer, layout)
        self._dt_ns = max(1, round(self._params.dt * 1e9))
        self._max_gap_ns = max(1, round(self._params.max_gap_s * 1e9))
        self._b_star = self._params.bias.threshold(self._params.pair.robot.u)
        self.reset("dissensus", None)

    # --- state -------------------------------------------------------------------------------

    @property
    def params(self) -> DecisionParams:
        """The engine's parameters."""
        return self._params

    @property
    def layout(self) -> TableLayout:
        """The table layout the observer reads poses against."""
        return self._observer.layout

    @property
    def z_r(self) -> float:
        """The robot opinion z_r (> 0 red, < 0 blue)."""
        return self._z_r

    @property
    def b_r(self) -> float:
        """The robot bias b_r (≡ 0 in dissensus mode)."""
        return self._b_r

    @property
    def z_hat(self) -> float:
        """The observed human opinion ẑ_h currently held."""
        return self._observer.z_hat

    @property
    def mode(self) -> Mode:
        """The trial mode: dissensus (controller off, b_r ≡ 0) or consensus (eq 6 toward O)."""
        return self._mode

    @property
    def option(self) -> Colour | None:
        """The consensus option O (None when not given)."""
        return self._option

    @property
    def t_ns(self) -> int | None:
        """Timestamp of the latest accepted pose, or None before the first pose."""
        return self._t_ns

    @property
    def b_star(self) -> float:
        """The bias threshold b* in use (BiasParams.threshold of the robot's u)."""
        return self._b_star

    def reset(self, mode: Mode, option: Colour | None) -> None:
        """Start a trial: z_r = b_r = 0, fresh observer, time unset.

        Raises ValueError for an unknown mode, an unknown option, or consensus mode without O.
        """
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if option not in ("red", "blue", None):
            raise ValueError(f"option must be 'red', 'blue' or None, got {option!r}")
        if mode == "consensus" and option is None:
            raise ValueError("consensus mode needs the consensus option O ('red' or 'blue')")
        self._mode: Mode = mode
        self._option: Colour | None = option
        self._z_r = 0.0
        self._b_r = 0.0
        self._t_ns: int | None = None
        self._observer.reset()
        self._observation = Observation(0.0, None, None, None, None, None, False, False)
        if mode == "consensus" and option is not None:
            self._sigma = sigma_for(option, self._params.bias)
            self._beta = beta_for(option, self._params.bias)
        else:
            self._sigma = self._beta = 0.0

    def on_trial(self, phase: str, mode: Mode, option: Colour | None) -> bool:
        """A protocol event: reset at "setup" and at "go" (opinions form from the cue on).

        O is taken in consensus trials only. True if the event reset the state. The decision
        service and offline re-runs of a recording (`nod replay --through decision`) both call
        this, so they reset alike.
        """
        if phase not in ("setup", "go"):
            return False
        self.reset(mode, option if mode == "consensus" else None)
        return True

    def accepts(self, t_ns: int) -> bool:
        """True if a pose stamped `t_ns` would advance the state (newer than the last one)."""
        return self._t_ns is None or t_ns > self._t_ns

    def set_layout(self, layout: TableLayout) -> None:
        """Use a new table layout for later poses (state and ẑ_h are kept)."""
        self._observer.layout = layout

    # --- stepping ----------------------------------------------------------------------------

    def on_hand(self, t_ns: int, landmarks: Sequence[Point] | None) -> DecisionOutput:
        """Advance to t_ns holding the previous ẑ_h, then read this pose (None: no hand).

        A timestamp that does not advance (repeated or out of order) is not integrated and the
        pose is not read; the current state is returned with the previous t_ns.
        """
        if self._t_ns is not None:
            gap_ns = t_ns - self._t_ns
            if gap_ns <= 0:
                return self._output()
            self._integrate(min(gap_ns, self._max_gap_ns), self._observer.z_hat)
        self._t_ns = t_ns
        self._observation = self._observer.update(landmarks, t_ns * 1e-9)
        return self._output()

    def _output(self) -> DecisionOutput:
        z_hat = self._observer.z_hat
        return DecisionOutput(
            t_ns=self._t_ns if self._t_ns is not None else 0,
            z_hat=z_hat,
            z_r=self._z_r,
            b_r=self._b_r,
            observation=self._observation,
            dissensus=self._z_r * z_hat < 0,
        )

    def _integrate(self, span_ns: int, z_hat: float) -> None:
        """RK4 over span_ns in steps of dt (the last one shorter), ẑ_h held (eq 1 and eq 6).

        The equations are `opinion_rate` (eq 1) and `bias_rate` (eq 6), the same functions the
        analysis and the tests use; the RK4 stages are written out for the pair (z_r, b_r) on
        plain floats because this runs ~8 steps per pose at 120 Hz (~33 at 30 Hz), where a
        generic stepper's tuples or NumPy's per-call overhead would dominate.
        """
        robot = self._params.pair.robot
        d, u, alpha = robot.d, robot.u, robot.alpha
        gamma_a = robot.gamma * self._params.pair.a_rh  # γ_r a_rh; ẑ_h is held (ZOH)
        rate, b_rate, active, tanh = opinion_rate, bias_rate, bias_active, math.tanh
        consensus = self._mode == "consensus"
        sigma, beta, b_star = self._sigma, self._beta, self._b_star
        b_max = self._params.bias.b_max
        z_r, b_r = self._z_r, self._b_r
        n_full, rest_ns = divmod(span_ns, self._dt_ns)
        steps = [self._dt_ns * 1e-9] * n_full
        if rest_ns:
            steps.append(rest_ns * 1e-9)
        for h in steps:
            hh = 0.5 * h
            k1z = rate(z_r, z_hat, b_r, d, u, alpha, gamma_a, tanh)
            # The freeze (eq 6 runs only while z_r · ẑ_h < 0) is decided once per step from the
            # state at its start: switching it inside the RK4 stages would make the right-hand
            # side discontinuous within a step and spoil the method's accuracy; the step is
            # short (1 ms) against the dynamics' time constants (1/d = 100 ms).
            if consensus and active(z_r, z_hat):
                k1b = b_rate(b_r, z_r, z_hat, sigma, beta, b_star)
                z2, b2 = z_r + hh * k1z, b_r + hh * k1b
                k2z = rate(z2, z_hat, b2, d, u, alpha, gamma_a, tanh)
                k2b = b_rate(b2, z2, z_hat, sigma, beta, b_star)
                z3, b3 = z_r + hh * k2z, b_r + hh * k2b
                k3z = rate(z3, z_hat, b3, d, u, alpha, gamma_a, tanh)
                k3b = b_rate(b3, z3, z_hat, sigma, beta, b_star)
                z4, b4 = z_r + h * k3z, b_r + h * k3b
                k4z = rate(z4, z_hat, b4, d, u, alpha, gamma_a, tanh)
                k4b = b_rate(b4, z4, z_hat, sigma, beta, b_star)
                b_r += (h / 6.0) * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)
                # Clamp |b_r| ≤ b_max after each step (SPEC §3): in dissensus the σ term never
                # stops on its own.
                if b_r > b_max:
                    b_r = b_max
                elif b_r < -b_max:
                    b_r = -b_max
            else:  # b_r frozen: only z_r moves
                k2z = rate(z_r + hh * k1z, z_hat, b_r, d, u, alpha, gamma_a, tanh)
                k3z = rate(z_r + hh * k2z, z_hat, b_r, d, u, alpha, gamma_a, tanh)
                k4z = rate(z_r + h * k3z, z_hat, b_r, d, u, alpha, gamma_a, tanh)
            z_r += (h / 6.0) * (k1z + 2.0 * k2z + 2.0 * k3z + k4z)
        self._z_r, self._b_r = z_r, b_r
