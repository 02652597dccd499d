"""The decision engine over N_o options: observer → robot opinion with eq 6 toward O.

`services.model.decision.DecisionModel` with vectors: each hand pose advances the robot's
state (z_r, s) from the previous pose's time with ẑ_h held (zero-order hold), by
`options_bias.advance_robot` (written on floats: `options_floats.advance`) in steps of
`DecisionParams.dt` and at most `max_gap_s`; then the pose updates ẑ_h (`OptionsObserver`).
b_r = s · option_vector(O) in a consensus trial, 0 in a dissensus one. Time comes from the
poses' timestamps alone, so a recorded stream replays identically. The same
`DecisionParams` as the two-option engine (dynamics, observer, eq 6).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from services.model.decision import DecisionParams
from services.model.dynamics import OptionsParams, option_vector
from services.model.geometry import OptionsLayout, Point
from services.model.observer_robust import OptionsObservation, OptionsObserver
from services.model.options_bias import split_span
from services.model.options_floats import advance
from services.model.protocol import MODES, Mode


@dataclass(frozen=True, slots=True)
class OptionsDecisionOutput:
    """The engine's state after one pose (vectors over the N_o options)."""

    t_ns: int
    z_hat: np.ndarray
    z_r: np.ndarray
    b_r: np.ndarray
    observation: OptionsObservation


class OptionsDecision:
    """Robot opinion z_r and bias b_r over N_o options, driven by observed hand poses."""

    def __init__(self, layout: OptionsLayout, params: DecisionParams | None = None) -> None:
        """An engine for a table of N_o boxes with the two-option engine's parameters."""
        self.params = params if params is not None else DecisionParams()
        self.layout = layout
        self.dynamics = OptionsParams(self.params.pair, n_options=layout.n_options)
        self._observer = OptionsObserver(layout, self.params.observer)
        self._dt_ns = max(1, round(self.params.dt * 1e9))
        self._max_gap_ns = max(1, round(self.params.max_gap_s * 1e9))
        self.reset("dissensus", None)

    @property
    def z_hat(self) -> np.ndarray:
        """The observed human opinion ẑ_h currently held."""
        return self._observer.z_hat

    @property
    def b_r(self) -> np.ndarray:
        """The robot's bias vector s · option_vector(O) (zero in dissensus)."""
        if self.option is None:
            return np.zeros(self.layout.n_options)
        return self.s * option_vector(self.option, self.layout.n_options)

    def reset(self, mode: Mode, option: int | None) -> None:
        """Start a trial: z_r = 0, s = 0, fresh observer; O is taken in consensus trials only."""
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if mode == "consensus" and option is None:
            raise ValueError("consensus mode needs the consensus option O")
        if option is not None and not 0 <= option < self.layout.n_options:
            raise ValueError(f"option must be in 0..{self.layout.n_options - 1}, got {option}")
        self.mode: Mode = mode
        self.option = option if mode == "consensus" else None
        self.z_r = np.zeros(self.layout.n_options)
        self.s = 0.0
        self.t_ns: int | None = None
        self._observer.reset()
        self._observation = self._observer.update(None)

    def on_hand(self, t_ns: int, landmarks: Sequence[Point] | None) -> OptionsDecisionOutput:
        """Advance to t_ns holding the previous ẑ_h, then read this pose (None: no hand).

        A timestamp that does not advance is not integrated and the pose is not read.
        """
        if self.t_ns is not None:
            gap_ns = t_ns - self.t_ns
            if gap_ns <= 0:
                return self._output()
            steps = split_span(min(gap_ns, self._max_gap_ns), self._dt_ns)
            self.z_r, self.s = advance(
                self.z_r, self.s, self._observer.z_hat, steps, self.dynamics, self.option,
                self.params.bias,
            )
        self.t_ns = t_ns
        self._observation = self._observer.update(landmarks, t_ns * 1e-9)
        return self._output()

    def _output(self) -> OptionsDecisionOutput:
        return OptionsDecisionOutput(
            self.t_ns if self.t_ns is not None else 0, self._observer.z_hat, self.z_r.copy(),
            self.b_r, self._observation,
        )
