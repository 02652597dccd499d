"""The decision engine: observer (eq 7) → robot opinion (eq 1) with the bias controller (eq 6).

Feed it hand poses with their source timestamps (`on_hand`). Between two poses the robot state
(z_r, b_r) is integrated with fixed-step RK4, holding the previously observed ẑ_h constant
(zero-order hold, SPEC §1); then the new pose updates ẑ_h, which only affects later intervals.
Time comes from the timestamps alone, so a recorded stream replays identically.

Two engines share that time handling (`PoseEngine`) and the parameters (`DecisionParams`):

- `DecisionModel`, the paper's two options (z_r, b_r and ẑ_h numbers, O a colour): the scalar
  RK4 of eq 1 and eq 6 in `DecisionModel._run`, the paper's kernel, which the study's golden
  and tests/unit/test_loop_speed.py hold bit for bit;
- `OptionsDecision`, any N_o ≥ 2 options (vectors, O an option index): the general RK4
  `rk4_robot` of the N_o-option rates (`services.model.dynamics`) and eq 6 toward O
  (`services.model.bias.options_bias_rate`), on plain floats. At N_o = 2 it agrees with the
  kernel to 1e-12 (tests/unit/test_decision_model.py: the integrators on random states, and
  the two engines on the same pose stream).

They are two classes, not one engine with N_o a parameter, because the paper's services,
replay and closed loop speak DecisionModel's scalar API (`DecisionOutput`, the colour of O,
the paper observer's `Observation`); giving it a vector form is left to the rig's fold.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Generic, NamedTuple, TypeVar

import numpy as np

from services.model.bias import (
    BiasParams,
    beta_for,
    options_bias_active,
    options_bias_rate,
    sigma_for,
)
from services.model.compiled import RK4Pair, pair_kernel, rk4_pair
from services.model.compiled import enabled as compiled_enabled
from services.model.dynamics import (
    OptionsParams,
    PairParams,
    float_rates,
    general_rates,
    leading_option,
    option_vector,
)
from services.model.geometry import Colour, OptionsLayout, Point, TableLayout
from services.model.observer import Observation, ObserverParams
from services.model.observer_robust import OptionsObservation, OptionsObserver, make_observer
from services.model.protocol import MODES, Mode

Held = TypeVar("Held")  # ẑ_h as an engine holds it: a number (two options) or an N_o-vector
Opt = TypeVar("Opt")  # the consensus option O: a colour (two options) or an option index
Out = TypeVar("Out")  # what an engine reports after each pose


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


def check_trial(mode: Mode, option: object, known: bool, options: str) -> None:
    """Refuse an unknown mode, an option not on the table, or consensus without O.

    `known` says whether the option is on the table; `options` names the valid ones.
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if not known:
        raise ValueError(f"option must be {options} or None, got {option!r}")
    if mode == "consensus" and option is None:
        raise ValueError(f"consensus mode needs the consensus option O ({options})")


class PoseEngine(Generic[Held, Opt, Out]):
    """What every decision engine does with time, for any number of options (module doc).

    A pose advances the state from the previous pose's time holding the ẑ_h read then
    (`advance`), by at most `max_gap_s` (stale input must not wind up the state), then is read
    (`read`); a pose whose timestamp does not advance is neither integrated to nor read. A
    subclass says what ẑ_h is held (`_held`), how the state is integrated over a span
    (`_integrate`), how a pose is read (`_observe`), what it reports (`_output`) and how a
    trial starts (`reset`, which calls `_restart_clock`).
    """

    _t_ns: int | None  # the latest accepted pose's timestamp

    def __init__(self, params: DecisionParams | None) -> None:
        self._params = params if params is not None else DecisionParams()
        self._dt_ns = max(1, round(self._params.dt * 1e9))
        self._max_gap_ns = max(1, round(self._params.max_gap_s * 1e9))
        self._restart_clock()

    @property
    def params(self) -> DecisionParams:
        """The engine's parameters."""
        return self._params

    @property
    def t_ns(self) -> int | None:
        """Timestamp of the latest accepted pose, or None before the first pose."""
        return self._t_ns

    def reset(self, mode: Mode, option: Opt | None) -> None:
        """Start a trial (the subclass's state, then `_restart_clock`)."""
        raise NotImplementedError

    def on_trial(self, phase: str, mode: Mode, option: Opt | None) -> bool:
        """A protocol event: reset at "setup" and at "go" (opinions form from the cue on).

        O is taken in consensus trials only. True if the event reset the state. The decision
        services and offline re-runs of a recording (`nod replay --through decision`) both
        call this, so they reset alike.
        """
        if phase not in ("setup", "go"):
            return False
        self.reset(mode, option if mode == "consensus" else None)
        return True

    def accepts(self, t_ns: int) -> bool:
        """True if a pose stamped `t_ns` would advance the state (newer than the last one)."""
        return self._t_ns is None or t_ns > self._t_ns

    def on_hand(self, t_ns: int, landmarks: Sequence[Point] | None) -> Out:
        """Advance to t_ns holding the previous ẑ_h, then read this pose (None: no hand).

        A timestamp that does not advance (repeated or out of order) is not integrated and the
        pose is not read; the current state is returned with the previous t_ns.
        """
        if not self.advance(t_ns):
            return self._output()
        return self.read(landmarks)

    def advance(self, t_ns: int) -> bool:
        """Integrate the robot's state to t_ns with the held ẑ_h; False if t_ns does not advance.

        The first half of `on_hand`: z_r at the pose's time does not depend on the pose itself
        (ẑ_h is held over the interval), so a caller can publish it before `read` the pose.
        """
        if self._t_ns is not None:
            gap_ns = t_ns - self._t_ns
            if gap_ns <= 0:
                return False
            self._integrate(min(gap_ns, self._max_gap_ns), self._held())
            self._last_gap_ns = gap_ns
        self._t_ns = t_ns
        return True

    def read(self, landmarks: Sequence[Point] | None) -> Out:
        """The second half of `on_hand`: update ẑ_h from the pose at the time `advance` set."""
        if self._t_ns is None:
            raise RuntimeError(
                f"{type(self).__name__}.read before advance: call advance(t_ns) first"
            )
        self._observe(landmarks, self._t_ns * 1e-9)
        return self._output()

    def _restart_clock(self) -> None:
        """Time unset: the next pose is a trial's first (not integrated to)."""
        self._t_ns = None
        self._last_gap_ns = 0

    def _held(self) -> Held:
        raise NotImplementedError

    def _integrate(self, span_ns: int, z_hat: Held) -> None:
        raise NotImplementedError

    def _observe(self, landmarks: Sequence[Point] | None, t: float) -> None:
        raise NotImplementedError

    def _output(self) -> Out:
        raise NotImplementedError


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


class DecisionModel(PoseEngine[float, Colour, DecisionOutput]):
    """Robot opinion z_r and bias b_r driven by observed hand poses (Algorithm 1).

    The paper's two options; `OptionsDecision` is the same engine over N_o options.
    """

    def __init__(self, params: DecisionParams | None = None, layout: TableLayout | None = None):
        p = params if params is not None else DecisionParams()
        self._observer = make_observer(p.observer, layout)
        self._b_star = p.bias.threshold(p.pair.robot.u)
        self._pair: RK4Pair | None = None  # `use_compiled`: `_run`'s steps as machine code
        super().__init__(p)
        self.reset("dissensus", None)

    # --- state -------------------------------------------------------------------------------

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
    def b_star(self) -> float:
        """The bias threshold b* in use (BiasParams.threshold of the robot's u)."""
        return self._b_star

    def reset(self, mode: Mode, option: Colour | None) -> None:
        """Start a trial: z_r = b_r = 0, fresh observer, time unset.

        Raises ValueError for an unknown mode, an unknown option, or consensus mode without O.
        """
        check_trial(mode, option, option in ("red", "blue", None), "'red' or 'blue'")
        self._mode: Mode = mode
        self._option: Colour | None = option
        self._z_r = 0.0
        self._b_r = 0.0
        self._restart_clock()
        self._ahead: list[tuple[float, float]] | None = None  # `look_ahead`'s states
        self._observer.reset()
        self._observation = Observation(0.0, None, None, None, None, None, False, False)
        if mode == "consensus" and option is not None:
            self._sigma = sigma_for(option, self._params.bias)
            self._beta = beta_for(option, self._params.bias)
        else:
            self._sigma = self._beta = 0.0
        self._hoist()

    def _hoist(self) -> None:
        """Make `rk4_pair`'s arguments that hold through a trial once, not twice a camera frame.

        −d, u, α; γ a_rh, which ẑ_h multiplies (in that order, as eq 1 does); the mode, σ, β, b*
        and b_max. Made anew whenever one of them may change (`reset`, `retune`).
        """
        robot, pair = self._params.pair.robot, self._params.pair
        self._kernel_args = (
            (float(-robot.d), float(robot.u), float(robot.alpha)),
            robot.gamma * pair.a_rh,
            (self._mode == "consensus", float(self._sigma), float(self._beta),
             float(self._b_star), float(self._params.bias.b_max)),
        )

    def retune(self, params: DecisionParams) -> None:
        """Use `params` from the next `reset` on (a policy's b* and u_r for a trial).

        The observer is the engine's own: parameters with another observer are refused.
        """
        if params.observer != self._params.observer:
            raise ValueError("retune keeps the engine's observer: its parameters cannot change")
        self._params = params
        self._dt_ns = max(1, round(params.dt * 1e9))
        self._max_gap_ns = max(1, round(params.max_gap_s * 1e9))
        self._b_star = params.bias.threshold(params.pair.robot.u)
        self._hoist()

    def use_compiled(self) -> None:
        """Take `_run`'s steps with the compiled kernel (`services.model.compiled`).

        The same values bit for bit, ~4× quicker; the offline loop's choice (a cohort's
        sessions), not the rig's: the decision service never imports the compiler.
        """
        if compiled_enabled():
            self._pair = pair_kernel()

    def set_layout(self, layout: TableLayout) -> None:
        """Use a new table layout for later poses (state and ẑ_h are kept)."""
        self._observer.layout = layout

    # --- stepping ----------------------------------------------------------------------------

    def _held(self) -> float:
        return self._observer.z_hat

    def _observe(self, landmarks: Sequence[Point] | None, t: float) -> None:
        self._observation = self._observer.update(landmarks, t)

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

        The steps are `compiled.rk4_pair` (eq 1 and eq 6 written out on plain floats, the
        constant parts hoisted): as Python here and on the rig, compiled after `use_compiled`.
        With a `path`, one step a call (the state after each is kept) until a fixed point.
        """
        held, gain, trial = self._kernel_args
        args = (*held, float(gain * z_hat), *trial)
        if path is None:
            steps = self._pair if self._pair is not None else rk4_pair
            z_r, b_r, _ = steps(z_r, b_r, z_hat, n, h, *args)
            return z_r, b_r
        for i in range(n):
            z_r, b_r, fixed = rk4_pair(z_r, b_r, z_hat, 1, h, *args)
            path.append((z_r, b_r))
            if fixed:  # every later step returns this state: known without computing it
                path.extend([(z_r, b_r)] * (n - 1 - i))
                break
        return z_r, b_r


# -- Over N_o options ----------------------------------------------------------------------------


def split_span(span_ns: int, dt_ns: int) -> list[float]:
    """The RK4 steps (s) that cover span_ns: whole steps of dt_ns, then the rest.

    The steps `DecisionModel._integrate` takes (its divmod), as a list for `rk4_robot`.
    """
    n_full, rest_ns = divmod(span_ns, dt_ns)
    steps = [dt_ns * 1e-9] * n_full
    if rest_ns:
        steps.append(rest_ns * 1e-9)
    return steps


Vector = Sequence[float] | np.ndarray  # an opinion over N_o options
Rates = Callable[[list[float], list[float]], list[float]]


def _robot_rates(p: OptionsParams, z_hat: Vector) -> Rates:
    """ż_r as a function of (z_r, b_r) over N_o options, ẑ_h held (ZOH), on plain floats.

    For β = δ = 0 (the paper's weights, the engine's) `float_rates`: `general_rates`' arithmetic
    without NumPy's per-call overhead on vectors of three, which would dominate the camera-rate
    loop (4-6× slower per 30 Hz pose, benchmarks/options_decision.py). Otherwise
    `general_rates` itself: the cross-option terms are written only there.
    """
    r = p.pair.robot
    social = [p.pair.a_rh * float(x) for x in z_hat]
    if p.beta == 0.0 and p.delta == 0.0:
        d, u, alpha, gamma = r.d, r.u, r.alpha, r.gamma

        def plain(z: list[float], b: list[float]) -> list[float]:
            return float_rates(z, social, b, d, u, alpha, gamma)

        return plain
    social_v = np.array(social)

    def crossed(z: list[float], b: list[float]) -> list[float]:
        rates = general_rates(np.array(z), social_v, np.array(b), r, p.beta, p.delta)
        return [float(x) for x in rates]

    return crossed


def rk4_robot(
    z_r: Vector,
    s: float,
    z_hat: Vector,
    steps: Sequence[float],
    p: OptionsParams,
    option: int | None,
    bias: BiasParams | None = None,
) -> tuple[np.ndarray, float]:
    """The robot's (z_r, s) over N_o options after RK4 `steps` (s), ẑ_h held: the general form.

    The bias is b_r = s · option_vector(O) (`services.model.bias`); `option` None: the
    controller is off, s frozen (a dissensus trial). The scheme is `DecisionModel._run`'s: the
    freeze decided once per step from the state at its start, s entering the stages at its
    value before the clamp and |s| clamped after the step; and the zero-sum subspace kept by
    construction (the last option set to minus the sum of the others after every step, as
    `services.model.dynamics.rk4_network`). At N_o = 2 it agrees with that kernel to 1e-12
    (tests/unit/test_decision_model.py). Returns the new z_r (an array) and s.
    """
    bp = bias if bias is not None else BiasParams()
    rates = _robot_rates(p, z_hat)
    b_star, sigma, gain, b_max = bp.threshold(p.pair.robot.u), bp.sigma, bp.K, bp.b_max
    n = p.n_options
    v = [float(x) for x in option_vector(option, n)] if option is not None else None
    h = leading_option(np.asarray(z_hat, dtype=float))
    z = [float(x) for x in z_r]
    z[-1] = -sum(z[:-1])
    zero = [0.0] * n
    for dt in steps:
        half = 0.5 * dt
        b = [s * vj for vj in v] if v is not None else zero
        k1 = rates(z, b)
        if v is not None and h is not None and options_bias_active(z, h):
            k1b = options_bias_rate(s, z[h], sigma, gain, b_star)
            z2 = [zj + half * kj for zj, kj in zip(z, k1, strict=True)]
            s2 = s + half * k1b
            k2 = rates(z2, [s2 * vj for vj in v])
            k2b = options_bias_rate(s2, z2[h], sigma, gain, b_star)
            z3 = [zj + half * kj for zj, kj in zip(z, k2, strict=True)]
            s3 = s + half * k2b
            k3 = rates(z3, [s3 * vj for vj in v])
            k3b = options_bias_rate(s3, z3[h], sigma, gain, b_star)
            z4 = [zj + dt * kj for zj, kj in zip(z, k3, strict=True)]
            s4 = s + dt * k3b
            k4 = rates(z4, [s4 * vj for vj in v])
            k4b = options_bias_rate(s4, z4[h], sigma, gain, b_star)
            s = min(b_max, max(-b_max, s + (dt / 6.0) * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)))
        else:  # s frozen: only z_r moves
            k2 = rates([zj + half * kj for zj, kj in zip(z, k1, strict=True)], b)
            k3 = rates([zj + half * kj for zj, kj in zip(z, k2, strict=True)], b)
            k4 = rates([zj + dt * kj for zj, kj in zip(z, k3, strict=True)], b)
        z = [zj + (dt / 6.0) * (a + 2.0 * (bb + c) + e)
             for zj, a, bb, c, e in zip(z, k1, k2, k3, k4, strict=True)]
        z[-1] = -sum(z[:-1])
    return np.array(z), s


@dataclass(frozen=True, slots=True)
class OptionsDecisionOutput:
    """The N_o-option engine's state after one pose (vectors over the N_o options)."""

    t_ns: int
    z_hat: np.ndarray
    z_r: np.ndarray
    b_r: np.ndarray
    observation: OptionsObservation


class OptionsDecision(PoseEngine[np.ndarray, int, OptionsDecisionOutput]):
    """Robot opinion z_r and bias b_r over N_o options, driven by observed hand poses.

    `DecisionModel` with vectors: the same `DecisionParams` (dynamics, observer, eq 6) and time
    handling (`PoseEngine`); ẑ_h is `OptionsObserver`'s reading of the table's N_o boxes, the
    robot's state (z_r, s) steps by `rk4_robot`, and b_r = s · option_vector(O) in a consensus
    trial, 0 in a dissensus one.
    """

    def __init__(self, layout: OptionsLayout, params: DecisionParams | None = None) -> None:
        """An engine for a table of N_o boxes with the two-option engine's parameters."""
        super().__init__(params)
        self.layout = layout
        self.dynamics = OptionsParams(self._params.pair, n_options=layout.n_options)
        self._observer = OptionsObserver(layout, self._params.observer)
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
        n = self.layout.n_options
        check_trial(mode, option, option is None or 0 <= option < n, f"an option in 0..{n - 1}")
        self.mode: Mode = mode
        self.option = option if mode == "consensus" else None
        self.z_r = np.zeros(n)
        self.s = 0.0
        self._restart_clock()
        self._observer.reset()
        self._observation = self._observer.update(None)

    def _held(self) -> np.ndarray:
        return self._observer.z_hat

    def _integrate(self, span_ns: int, z_hat: np.ndarray) -> None:
        self.z_r, self.s = rk4_robot(
            self.z_r, self.s, z_hat, split_span(span_ns, self._dt_ns), self.dynamics,
            self.option, self._params.bias,
        )

    def _observe(self, landmarks: Sequence[Point] | None, t: float) -> None:
        self._observation = self._observer.update(landmarks, t)

    def _output(self) -> OptionsDecisionOutput:
        return OptionsDecisionOutput(
            self._t_ns if self._t_ns is not None else 0, self._observer.z_hat, self.z_r.copy(),
            self.b_r, self._observation,
        )
