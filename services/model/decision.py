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

from services.model.bias import BiasParams, beta_for, sigma_for
from services.model.dynamics import PairParams
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
        self._ahead: list[tuple[float, float]] | None = None  # `look_ahead`'s states
        self._last_gap_ns = 0
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
        if not self.advance(t_ns):
            return self._output()
        return self.read(landmarks)

    def advance(self, t_ns: int) -> bool:
        """Integrate (z_r, b_r) to t_ns with the held ẑ_h; False if t_ns does not advance.

        The first half of `on_hand`: z_r at the pose's time does not depend on the pose itself
        (ẑ_h is held over the interval), so a caller can publish it before `read` the pose.
        """
        if self._t_ns is not None:
            gap_ns = t_ns - self._t_ns
            if gap_ns <= 0:
                return False
            self._integrate(min(gap_ns, self._max_gap_ns), self._observer.z_hat)
            self._last_gap_ns = gap_ns
        self._t_ns = t_ns
        return True

    def read(self, landmarks: Sequence[Point] | None) -> DecisionOutput:
        """The second half of `on_hand`: update ẑ_h from the pose at the time `advance` set."""
        if self._t_ns is None:
            raise RuntimeError("DecisionModel.read before advance: call advance(t_ns) first")
        self._observation = self._observer.update(landmarks, self._t_ns * 1e-9)
        return self._output()

    def look_ahead(self) -> None:
        """Integrate the next interval's full steps now, before its pose arrives.

        Between two poses ẑ_h is held, so the states after each full RK4 step from the last pose
        on are known before the next pose: computed here (e.g. once the outputs are out), the
        next `advance` only looks up its state and takes the last, shorter step. The steps are
        those `advance` would take, in the same order, so every value is bit for bit the same;
        as many as the last gap had plus two (a late pose integrates the rest itself).
        """
        if self._t_ns is None or self._ahead is not None:
            return
        n = min(self._last_gap_ns, self._max_gap_ns) // self._dt_ns + 2
        path: list[tuple[float, float]] = []
        self._run(self._z_r, self._b_r, self._observer.z_hat, n, self._dt_ns * 1e-9, path)
        self._ahead = path

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

        Full steps already taken by `look_ahead` are looked up, not recomputed.
        """
        n_full, rest_ns = divmod(span_ns, self._dt_ns)
        z_r, b_r = self._z_r, self._b_r
        ahead, self._ahead = self._ahead, None
        if ahead:
            known = min(n_full, len(ahead))
            if known:
                z_r, b_r = ahead[known - 1]
            n_full -= known
        if n_full:
            z_r, b_r = self._run(z_r, b_r, z_hat, n_full, self._dt_ns * 1e-9)
        if rest_ns:
            z_r, b_r = self._run(z_r, b_r, z_hat, 1, rest_ns * 1e-9)
        self._z_r, self._b_r = z_r, b_r

    def _run(
        self,
        z_r: float,
        b_r: float,
        z_hat: float,
        n: int,
        h: float,
        path: list[tuple[float, float]] | None = None,
    ) -> tuple[float, float]:
        """Take n RK4 steps of h from (z_r, b_r), ẑ_h held; each step's state appended to `path`.

        The equations are `opinion_rate` (eq 1) and `bias_rate` (eq 6), the functions the
        analysis and the tests use, written out here with the same float operations in the same
        order (so every value is bit for bit theirs; tests/unit/test_loop_speed.py checks
        it) and their constant parts hoisted (−d, γ_r a_rh ẑ_h and the sign of ẑ_h: ẑ_h is
        held). The RK4 stages are written out for the pair (z_r, b_r) on plain floats because
        this runs ~8 steps per pose at 120 Hz (~33 at 30 Hz, ~1000 steps per simulated second),
        where a generic stepper's tuples, NumPy's per-call overhead, or even a function call per
        stage (half the step's cost) would dominate.
        """
        robot = self._params.pair.robot
        nd, u, alpha = -robot.d, robot.u, robot.alpha
        gz = robot.gamma * self._params.pair.a_rh * z_hat
        tanh = math.tanh
        consensus = self._mode == "consensus"
        sigma, beta, b_star = self._sigma, self._beta, self._b_star
        b_max = self._params.bias.b_max
        sgn = 1.0 if z_hat > 0 else -1.0  # `bias_rate`'s sign of ẑ_h, held with it
        hh, h6 = 0.5 * h, h / 6.0
        copysign = math.copysign
        for i in range(n):
            z0, b0 = z_r, b_r
            k1z = nd * z_r + u * tanh(alpha * z_r + gz) + b_r
            # The freeze (eq 6 runs only while z_r · ẑ_h < 0) is decided once per step from the
            # state at its start: switching it inside the RK4 stages would make the right-hand
            # side discontinuous within a step and spoil the method's accuracy; the step is
            # short (1 ms) against the dynamics' time constants (1/d = 100 ms).
            if consensus and z_r * z_hat < 0:  # `bias_active`: the pair is in dissensus
                k1b = sigma * z_r * sgn + beta * max(0.0, b_star - abs(b_r))
                z2, b2 = z_r + hh * k1z, b_r + hh * k1b
                k2z = nd * z2 + u * tanh(alpha * z2 + gz) + b2
                k2b = sigma * z2 * sgn + beta * max(0.0, b_star - abs(b2))
                z3, b3 = z_r + hh * k2z, b_r + hh * k2b
                k3z = nd * z3 + u * tanh(alpha * z3 + gz) + b3
                k3b = sigma * z3 * sgn + beta * max(0.0, b_star - abs(b3))
                z4, b4 = z_r + h * k3z, b_r + h * k3b
                k4z = nd * z4 + u * tanh(alpha * z4 + gz) + b4
                k4b = sigma * z4 * sgn + beta * max(0.0, b_star - abs(b4))
                b_r += h6 * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)
                # Clamp |b_r| ≤ b_max after each step (SPEC §3): in dissensus the σ term never
                # stops on its own.
                if b_r > b_max:
                    b_r = b_max
                elif b_r < -b_max:
                    b_r = -b_max
            else:  # b_r frozen: only z_r moves
                z2 = z_r + hh * k1z
                k2z = nd * z2 + u * tanh(alpha * z2 + gz) + b_r
                z3 = z_r + hh * k2z
                k3z = nd * z3 + u * tanh(alpha * z3 + gz) + b_r
                z4 = z_r + h * k3z
                k4z = nd * z4 + u * tanh(alpha * z4 + gz) + b_r
            z_r += h6 * (k1z + 2.0 * k2z + 2.0 * k3z + k4z)
            if path is not None:
                path.append((z_r, b_r))
            if (  # a fixed point of the step, bit for bit (the sign of a zero included)
                z_r == z0
                and b_r == b0
                and copysign(1.0, z_r) == copysign(1.0, z0)
                and copysign(1.0, b_r) == copysign(1.0, b0)
            ):
                # The step is a function of (z_r, b_r) alone (ẑ_h, h and the mode are held), so
                # every later step returns this state too: the rest is known without computing
                # it. Held hands (before "go", after a press, a still participant) get here.
                if path is not None:
                    path.extend([(z_r, b_r)] * (n - 1 - i))
                break
        return z_r, b_r
