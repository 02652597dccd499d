"""A synthetic participant: eq 2 for the opinion, a kinematic hand, 21 noisy landmarks.

One person for any table of N_o ≥ 2 boxes (the paper's two, red and blue, or an `OptionsLayout`).
The participant's internal opinion follows eq 2,
    ż_h = −d z_h + u tanh(α z_h + γ_h · r̂) + b_h,
where r̂ is what the participant sees of the robot (the box the arm heads for, after a
perception delay) and γ_h > 0 because the participant's objective is to *match* the robot
(the paper's γ < 0 models the robot's deliberate disagreement, not the person's goal). The bias
b_h = preference + gaze: a seeded random preference per trial (a box and a strength), plus the
gaze cue's pull toward the box the eyes look at, scaled by the cue's strength (|yaw| on the
paper's table, `gaze.read_gaze` on any) and a trust that grows after trials where following the
gaze paid off.

The opinion steers a hand: after a reaction time the hand heads for the leading box, its speed
scaled by conviction (low conviction = hesitation). Once past the commit line a rule-abiding
participant keeps its choice; it switches at most `max_switches` times. The hand is published
as 21 landmarks around its centre with Gaussian noise, exactly as vision would.

In a control trial a strategist (`late_switch_*`, off by default) may instead play the paper's
"quick, strategic end-moment switch": keep to the first box whatever the arm does, then, just
before the commit line, turn quickly for the box the arm is at, too late for it to follow. The
more control trials have shown the arm opposing them, the likelier they play it.

In a consensus trial a contrarian (`contrarian_*`, off by default) distrusts the eyes: they head
for a box the eyes do not look at, and then follow the arm to O (a pliant one, CH) or mostly
hold their box (a firm one, D). Each consensus trial so played makes the next less likely,
except for a persistent one, who plays them all so.

**Two boxes and N_o.** Over options (docs/multi-option.md) z_h is an N_o-vector on the zero-sum
subspace, ż_h = F − mean(F) (`dynamics.float_rates`), r̂ = option_vector(the arm's box) and the
preference and the pull are along their boxes' `option_vector`s. With two boxes this is eq 2 on
x = z_0 = −z_1 (`dynamics`' reduction), so two boxes are stepped by the scalar eq 2 itself, the
class's two-option kernel (`_step`, the paper's arithmetic, hot in a cohort), and N_o ≥ 3 by the
general form (`_step_general`); everything else (draws, traits, the arm seen, the hand, the
press, the camera) is one code. Random numbers are drawn in the same order for any N_o, so two
boxes draw what the paper's person drew, and tests/unit/test_participant.py holds the
general form on two boxes to the kernel bit for bit (opinion, hand, presses, landmarks).

Pure: time is an argument, randomness comes from a seeded numpy Generator.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Generic, TypeVar, cast, overload

import numpy as np

from services.model.compiled import (
    C_SIZE,
    S_FEINT,
    S_LAST,
    S_PRESSED,
    S_QUICK,
    S_SIZE,
    S_T,
    SEEN,
    Camera,
    PersonSteps,
    camera_kernel,
    eq2_step,
    person_kernel,
    person_steps,
)
from services.model.compiled import enabled as compiled_enabled
from services.model.dynamics import AgentParams, float_rates, option_vector
from services.model.gaze import GazeCommand, read_gaze
from services.model.geometry import (
    COLOURS,
    HAND_TEMPLATE,
    Colour,
    OptionsLayout,
    Point,
    TableLayout,
)

# What the person calls an option: a colour on the paper's table, a box index over N_o boxes.
Opt = TypeVar("Opt", Colour, int)


@dataclass(frozen=True, slots=True)
class ParticipantParams:
    """A participant's traits; `jittered` draws one person of a cohort around these."""

    agent: AgentParams = field(default_factory=lambda: AgentParams(gamma=3.0))  # γ_h > 0: follow
    preference_mean: float = 2.6  # |b_h| of the private preference, drawn per trial
    preference_sd: float = 0.6  # its trial-to-trial sd around the person's own mean
    # Person-to-person sd of preference_mean: how much of the preference's variance lies between
    # people rather than between one person's trials (a strong-willed person stays D, a pliant
    # one CH, trial after trial: the consistency the paper's Fig 8b flows show).
    preference_spread: float = 0.4
    gaze_gain: float = 7.0  # b_h pull per radian of gaze yaw, times trust (the cohort's median)
    # Person-to-person spread of gaze_gain (sd of its log): people differ a lot in how much they
    # use the eyes (the paper's Q2, "did you use the hints", has sd 3.8 on a 1-10 scale).
    gaze_gain_spread: float = 0.5
    trust0: float = 0.9  # trust in the gaze at trial 4
    trust_step: float = 0.25  # trust gained after a consensus trial that followed the gaze
    # How much a person who trusts the eyes discounts an arm heading against them: the arm's
    # pull is divided by (1 + gaze_over_robot · trust) while it contradicts the gaze. 0 = the arm
    # is believed whatever the eyes say. Without it, people heading where the eyes look followed
    # the robot's first move the other way (before its bias won) and ended DH in 9-16 % of
    # consensus trials, where the paper saw 0-2 %.
    gaze_over_robot: float = 0.0
    perception_delay_s: float = 0.25  # how late the participant sees the arm's heading
    reaction_s: float = 0.30  # from "go" to the first hand movement
    speed: float = 0.32  # peak hand speed, normalised image units per second
    accel: float = 3.0  # hand acceleration limit (units/s²)
    full_conviction: float = 0.40  # |z_h| at which the hand moves at full speed
    # Speed (as a share of `speed`) below which nobody hesitates: a torn person still moves,
    # slowly (without it, a preference and a gaze pull that cancel froze hands until timeout).
    min_conviction: float = 0.25
    max_switches: int = 1  # the rules allow one change of path
    # Probability that a person allows themselves that change in a control (dissensus) trial;
    # the paper saw almost no hesitation there (no DH, ~1% CH in trials 1-3).
    control_switch_prob: float = 1.0
    # The strategic late switch of the control trials (the paper's Sec 6: "quick, strategic
    # end-moment switches" gave some people the robot's buzzer although it disagreed; its Fig 8a
    # has ~29 % C in trials 1-3, and 16 of its 51 people are C in most control trials, so the C
    # gather in the same people). A strategist heads for their own side as a feint, keeps to it,
    # and just before the commit line turns at speed for the side the arm is on: the arm, parked
    # on that side, needs ~1.3 s to notice, pause and cross back past the middle (docs/study.md).
    # Share of people who are strategists (drawn once per person); 0 = nobody (the SPEC person).
    late_switch_share: float = 0.0
    # Chance a strategist plays it in their first control trial, before seeing the arm oppose them.
    late_switch_first: float = 0.5
    # Share of a strategist's remaining doubt gone after each control trial in which the arm was
    # seen heading against their first choice: the strategy grows as they learn it disagrees.
    late_switch_learn: float = 0.5
    # Hand speed during the switch, as a multiple of `speed`: the switch is quick (the paper's
    # instructions list "switching too quickly" among the don'ts) so the arm cannot follow.
    late_switch_speed: float = 1.5
    # How far before the commit line (normalised image units) the turn starts: as late as the
    # rules allow. The observer reads a turn only once the hand heads clearly sideways, ~0.3 s
    # on, so most turns begun 0.03 before the line were read past it (a violation), none of 180
    # begun 0.1 before it (at 1.5× speed; a quicker turn needs more).
    late_switch_lead: float = 0.1
    # The person who distrusts the eyes (the paper's Fig 8b: 12 of its 51 people are mostly CH
    # and 7 mostly D in trials 4-8, and at least 3 are D in trial 4, O blue, and trial 5, O red,
    # which a fair coin per trial or a favourite colour cannot give): in a consensus trial a
    # contrarian ignores the gaze and heads for the other box; the arm, going for O, then brings
    # them over (CH) or not (D, a strong-willed one), trial after trial. Share of such people,
    # drawn once per person; 0 = nobody (the SPEC person, its random stream unchanged).
    contrarian_share: float = 0.0
    # Share of a contrarian's distrust gone after each consensus trial played against the eyes:
    # they come round as the eyes and the robot keep agreeing (the paper's D falls 14 -> 2 %
    # from trial 5 to 7, its CH 24 -> 14 %).
    contrarian_learn: float = 0.3
    # How firmly a pliant contrarian holds the other box: their preference's size, times this, in
    # a trial played against the eyes. Below 1 the arm brings most of them over (CH: the paper's
    # trial 4 has 43 % CH and 12 % D, so most of those who first went the other way came over).
    contrarian_resolve: float = 1.0
    # Share of contrarians who are firm instead: they hold the other box with their whole
    # preference and mostly stay there (D), the paper's 7 of 51 mostly-D people; drawn once.
    contrarian_firm: float = 0.0
    # Share of contrarians who are persistent: they learn nothing from the eyes and the robot
    # agreeing and play every consensus trial against the eyes (drawn once, apart from firm).
    # The paper's CH is 12 % still in trial 8 and 12 of its 51 people are CH in most of trials
    # 4-8, which a contrarian who comes round after a trial or two cannot be (docs/study.md).
    contrarian_persist: float = 0.0
    rule_breaking: float = 0.05  # probability per trial of ignoring the commit-line rule
    hand_radius: float = 0.03  # landmark spread around the centre
    # Tracker jitter (sd, normalised units; 1 px = 1/640 in x, 1/480 in y). A tracker's error is
    # mostly common to the whole hand (it shifts the fitted hand) plus a little per landmark.
    # benchmarks/tracker_jitter.py measures the aruco tracker at ≈ 0.2 px on a still hand
    # through a cheap camera (mostly the hand's own tremor); ≈ 2 px is a MediaPipe-class
    # tracker's (1-3 px), the harsher case the observer must survive: see docs/observer.md.
    common_noise: float = 0.003  # the whole hand, frame to frame (≈ 2 px at 640×480)
    landmark_noise: float = 0.001  # each landmark on top (≈ 0.6 px)
    start: Point = (0.5, 0.85)  # rest position of the hand, participant's side of the table

    def __post_init__(self) -> None:
        for name in ("speed", "accel", "full_conviction", "hand_radius"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ParticipantParams.{name} must be > 0")
        for name in ("gaze_gain_spread", "gaze_over_robot", "preference_sd", "preference_spread"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"ParticipantParams.{name} must be >= 0")
        for name in (
            "rule_breaking",
            "control_switch_prob",
            "min_conviction",
            "late_switch_share",
            "late_switch_first",
            "late_switch_learn",
            "contrarian_share",
            "contrarian_learn",
            "contrarian_firm",
            "contrarian_persist",
        ):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"ParticipantParams.{name} must be in [0, 1]")
        if not 0 <= self.contrarian_resolve <= 2:
            raise ValueError("ParticipantParams.contrarian_resolve must be in [0, 2]")
        if not 1 <= self.late_switch_speed <= 5:
            raise ValueError("ParticipantParams.late_switch_speed must be in [1, 5] (× speed)")
        if not 0 <= self.late_switch_lead <= 0.3:
            raise ValueError("ParticipantParams.late_switch_lead must be in [0, 0.3]")


class Participant(Generic[Opt]):
    """One simulated person over a session of trials, at a table of N_o ≥ 2 boxes.

    The layout sets the person's vocabulary: on the paper's table (`TableLayout`) options are
    colours and the arm's heading a sign, as the paper's services speak; over an `OptionsLayout`
    options are box indices. Inside, boxes are indices either way (red is 0, as
    `OptionsLayout.from_table`) and everything but the opinion's RK4 step is one code: the
    draws, the traits, what the arm is seen doing, the hand, the press and the camera.
    """

    @overload
    def __init__(
        self: Participant[Colour], params: ParticipantParams, layout: TableLayout, seed: int,
        *, general: bool = False,
    ) -> None: ...

    @overload
    def __init__(
        self: Participant[int], params: ParticipantParams, layout: OptionsLayout, seed: int,
        *, general: bool = False,
    ) -> None: ...

    def __init__(
        self, params: ParticipantParams, layout: TableLayout | OptionsLayout, seed: int,
        *, general: bool = False,
    ) -> None:
        """A person at `layout`, its draws from `seed`.

        `general`: step the opinion as an N_o-vector even on two boxes (where the scalar
        kernel is otherwise used); the property test holding the two together needs it.
        """
        self.p = params
        self.layout = layout
        self._paper = isinstance(layout, TableLayout)  # colours, signs and the paper's yaw
        self.table = OptionsLayout.from_table(layout) if isinstance(layout, TableLayout) else layout
        self.n = self.table.n_options
        self.general = general or self.n > 2
        labels = COLOURS if self._paper else tuple(range(self.n))
        self._labels: tuple[Opt, ...] = cast("tuple[Opt, ...]", labels)
        self._vectors = tuple(tuple(option_vector(j, self.n).tolist()) for j in range(self.n))
        self.rng = np.random.default_rng(seed)
        self.trust = params.trust0
        self._x, self._y = params.start
        self._vx = self._vy = 0.0
        # How far a landmark sticks out of the hand's centre: nearer a box than this, test it.
        self._reach = float(np.abs(HAND_TEMPLATE).max()) * params.hand_radius
        # Fixed for the person's life (params and layout are frozen): computed once, not every
        # 2 ms step. The same floats the layout's properties return, so the same motion.
        self._hand = HAND_TEMPLATE * params.hand_radius  # the landmarks around a zero centre
        self._centers = tuple(b.center for b in self.table.boxes)
        reach = self._reach
        self._near = tuple(  # per box: where the hand's centre may put a landmark inside it
            (b.x1 - reach, b.x2 + reach, b.y1 - reach, b.y2 + reach) for b in self.table.boxes
        )
        self._commit_y = self.table.commit.y
        self._commit_below = self.table.commit.start_side == "below"
        # The opinion: z_h (a float) is the two-option kernel's x = z_0 = −z_1 (> 0: box 0, red);
        # the general form holds the N_o-vector in _z (Σ = 0) and keeps z_h = _z[0] (`opinion`).
        self.z_h = 0.0
        self.b_h = 0.0
        self._z = [0.0] * self.n
        self._b = [0.0] * self.n
        self.t_go: float | None = None
        self.t = 0.0
        self.pressed: Opt | None = None
        self.switches = 0
        self._heading: int | None = None  # the box the hand heads for
        self._obeys_commit = True
        self._robot_seen: deque[tuple[float, int | None]] = deque()  # (t, the arm's box)
        self._gaze: GazeCommand | float = 0.0
        self._pref_box = 0  # today's preference: a box and a strength (≥ 0)
        self._strength = 0.0
        self._cue: int | None = None  # the box the eyes' cue is taken for (None: no cue)
        self._pull = 0.0
        self._last_box: int | None = None  # the arm's box as last seen, None still
        self._max_switches = params.max_switches
        # The strategic late switch (ParticipantParams.late_switch_*). Drawn only when anyone can
        # be a strategist, so the SPEC person's random stream, hence its sessions, are unchanged.
        share = params.late_switch_share
        self.strategist = share > 0 and bool(self.rng.random() < share)
        self.opposed_trials = 0  # control trials in which the arm headed against the first choice
        self._control = False
        self._feint = False  # playing the late switch this trial: first box until the line
        self._quick = False  # turned late toward the arm: straight on, at the switch's speed
        self._first: int | None = None  # the box the hand first headed for this trial
        self._arm_box: int | None = None  # the box the arm was last seen heading for (parked)
        self._opposed = False  # the arm was seen heading against the first box this trial
        # The contrarian (ParticipantParams.contrarian_*), drawn like the strategist: only when
        # anyone can be one, so a person without them keeps the random stream it had.
        c_share = params.contrarian_share
        # Drawn apart from the strategist: the paper's lasting CH and D come from both control
        # rows of Fig 8b (C → CH 4, C → D 2 of 16; D → CH 8, D → D 5 of 35). Contrarians only
        # among non-strategists fitted the D row better and the C row worse (docs/study.md).
        self.contrarian = c_share > 0 and bool(self.rng.random() < c_share)
        self.firm = self.contrarian and bool(self.rng.random() < params.contrarian_firm)
        self._resolve = 1.0 if self.firm else params.contrarian_resolve
        # Drawn only when anyone can be persistent: a cohort without them keeps its stream.
        p_share = params.contrarian_persist
        self.persistent = self.contrarian and p_share > 0 and bool(self.rng.random() < p_share)
        self._learn = 0.0 if self.persistent else params.contrarian_learn
        self.contrary_trials = 0  # consensus trials played against the eyes so far
        self._contrary = False  # against the eyes this trial
        # The two-box steps (`compiled.person_steps`: as Python, or compiled after
        # `use_compiled`), the trial's constants (made at its first step, dropped whenever one
        # of them may change) and the state vector: lists as Python, arrays compiled.
        self._steps: PersonSteps = person_steps
        self._compiled = False
        # The camera's noisy landmarks as one compiled call (`compiled.camera_landmarks`), or
        # None: NumPy's expression (the rig; the reference).
        self._camera: Camera | None = None
        self._consts: np.ndarray | list[float] | None = None
        self._state: np.ndarray | list[float] = [0.0] * S_SIZE

    def use_compiled(self) -> None:
        """Step two boxes with the compiled loop (`compiled.person_steps`), the same values.

        The offline loop's choice (`closed_loop`); N_o ≥ 3 boxes keep the Python steps. The
        camera's landmarks are compiled on any table (`compiled.camera_landmarks`).
        """
        if not compiled_enabled():
            return
        self._camera = camera_kernel()
        if not self.general:
            self._steps = person_kernel()
            self._compiled = True
            self._consts = None
            self._state = np.zeros(S_SIZE)

    def _draw_box(self, n: int) -> int:
        """One of n choices, uniform, from one `random()`: below 0.5 is the first of two.

        One draw for any n, so two boxes draw as the paper's person drew the preference's
        sign (`random() < 0.5` for red).
        """
        return min(int(self.rng.random() * n), n - 1)

    # -- protocol events -------------------------------------------------------------------

    def see_gaze(self, gaze: GazeCommand | float) -> None:
        """The eyes' current gaze cue (not the attention gesture's poses).

        A float is the paper's rig's yaw (> 0 toward red), a `GazeCommand` the full pose.
        """
        self._gaze = gaze

    def new_trial(self, option: Opt | None) -> None:
        """Prepare for a trial ("setup", `option` its O or None): draw today's preference."""
        self._consts = None
        self._strength = abs(self.rng.normal(self.p.preference_mean, self.p.preference_sd))
        self._pref_box = self._draw_box(self.n)
        self._cue, self._pull = None, 0.0
        if self.general:
            self._z = [0.0] * self.n
            self._b = [self._strength * v for v in self._vectors[self._pref_box]]
            self.b_h = self._b[0]
        else:
            self.b_h = self._strength * (1 if self._pref_box == 0 else -1)
        self.z_h = 0.0
        self._x, self._y = self.p.start
        self._vx = self._vy = 0.0
        self.t_go = None
        self.pressed = None
        self.switches = 0
        self._heading = None
        self._obeys_commit = self.rng.random() >= self.p.rule_breaking
        allowed = option is not None or self.rng.random() < self.p.control_switch_prob
        self._max_switches = self.p.max_switches if allowed else 0
        self._robot_seen.clear()
        self._last_box = None
        self._control = option is None
        chance = late_switch_chance(
            self.p.late_switch_first, self.p.late_switch_learn, self.opposed_trials
        )
        self._feint = self._control and self.strategist and bool(self.rng.random() < chance)
        self._contrary = (
            not self._control
            and self.contrarian
            and bool(self.rng.random() < (1.0 - self._learn) ** self.contrary_trials)
        )
        self._quick = False
        self._first = None
        self._arm_box = None
        self._opposed = False

    def _read_gaze(self) -> tuple[int | None, float]:
        """(the box the gaze points to or None, its strength): the paper's yaw on its table."""
        gaze = self._gaze
        if self._paper:  # the paper's rig: the side of the yaw, > 0 red, whatever the layout
            yaw = gaze if isinstance(gaze, float | int) else gaze.yaw
            return (None if abs(yaw) <= 1e-9 else 0 if yaw > 0 else 1), abs(yaw)
        return read_gaze(self.table, gaze if isinstance(gaze, GazeCommand) else GazeCommand(gaze))

    def go(self, t: float) -> None:
        """The countdown said "go": the bias is today's preference plus the gaze cue's pull.

        The gaze is read at "go", when the participant has watched the eyes settle through the
        countdown (the attention gesture before trial 4 is over by then). A contrarian playing
        this trial against the eyes prefers a box they do not look at (their own if it is one,
        else one of the others, drawn: with two boxes there is one, and no draw).
        """
        cue, strength = self._read_gaze()
        pull = self.p.gaze_gain * strength * self.trust
        if self._contrary and cue is not None:  # today's preference is a box not looked at
            if self._pref_box == cue:
                others = [j for j in range(self.n) if j != cue]
                self._pref_box = others[self._draw_box(len(others))] if len(others) > 1 else (
                    others[0])
            self._strength *= self._resolve
            self.contrary_trials += 1
            cue, pull = None, 0.0  # the eyes: neither pull nor lesson
        self._cue, self._pull = cue, pull
        box, s = self._pref_box, self._strength
        if self.general:
            b = [s * v for v in self._vectors[box]]
            if cue is not None:
                b = [bj + pull * c for bj, c in zip(b, self._vectors[cue], strict=True)]
            self._b = b
            self.b_h = b[0]
        else:  # b_h = preference ± pull, the paper person's arithmetic
            gaze_sign = 0 if cue is None else 1 if cue == 0 else -1
            self.b_h = s * (1 if box == 0 else -1) + gaze_sign * pull
        self.t_go = t
        self._consts = None

    def trial_ended(self, robot: Opt | None) -> None:
        """Learn from the trial: following the gaze and agreeing with the robot builds trust.

        A control trial whose arm headed against the person's first choice teaches a strategist
        that the robot disagrees (`late_switch_chance`).
        """
        self._consts = None  # trust may change (and the person steps on until the next setup)
        if self._control and self._opposed:
            self.opposed_trials += 1
        if self._cue is not None and robot is not None and self.pressed is not None:
            followed = self._labels.index(self.pressed) == self._cue
            if followed and self.pressed == robot:
                self.trust += self.p.trust_step
            elif followed:
                self.trust = max(0.0, self.trust - self.p.trust_step)

    def see_robot(self, t: float, heading: int | None) -> None:
        """What the arm is doing now.

        On the paper's table (`TableLayout`) its sign, as the paper's services give it: +1
        toward red, −1 toward blue, 0 still. Over an `OptionsLayout`: the box it heads for,
        None when still.
        """
        if self._paper:
            self._robot_seen.append((t, None if not heading else 0 if heading > 0 else 1))
        else:
            self._robot_seen.append((t, heading))

    # -- dynamics --------------------------------------------------------------------------

    def _arm_seen(self) -> tuple[int | None, float]:
        """(the arm's box as seen now, None still; the weight of its pull).

        Seen `perception_delay_s` late. The weight is 1, or 1 / (1 + gaze_over_robot · trust)
        while the arm heads against the eyes' cue. Notes where the arm is parked and whether it
        opposes the first choice (the strategist's lesson).
        """
        cutoff = self.t - self.p.perception_delay_s
        seen = self._robot_seen
        while seen and seen[0][0] <= cutoff:
            self._last_box = seen.popleft()[1]
        box = self._last_box
        if box is None:
            return None, 1.0
        self._arm_box = box
        if self._first is not None and box != self._first:
            self._opposed = True
        if self._cue is not None and box != self._cue:  # the arm goes against the eyes
            return box, 1.0 / (1.0 + self.p.gaze_over_robot * self.trust)
        return box, 1.0

    def advance(self, t: float, dt: float = 0.002) -> None:
        """Integrate opinion (eq 2, RK4 with r̂ held) and hand motion up to time t."""
        if self.t_go is None or self.pressed is not None:
            self.t = max(self.t, t)  # at rest (before "go" or after the press): nothing evolves
            return
        if self.t < self.t_go:
            self.t = min(t, self.t_go)
        if not self.general:
            self._advance_steps(t, dt)
            return
        while self.t < t - 1e-12:
            left = t - self.t
            h = left if left < dt else dt  # min(dt, left)
            self._step_general(h)
            self.t += h

    def _constants(self) -> list[float]:
        """The trial's constants of `compiled.person_steps` (its C_* order), after "go"."""
        p, a = self.p, self.p.agent
        assert self.t_go is not None
        (c0x, c0y), (c1x, c1y) = self._centers
        line = self.table.commit
        below = line.start_side == "below"
        return [
            self.b_h, -a.d, a.u, a.alpha, a.gamma, self.t_go + p.reaction_s,
            p.perception_delay_s, -1 if self._cue is None else self._cue,
            1.0 / (1.0 + p.gaze_over_robot * self.trust), p.full_conviction,
            p.min_conviction, p.speed, p.late_switch_speed, p.accel, self._commit_y,
            self._commit_below, self._obeys_commit, self._max_switches,
            c0x, c0y, c1x, c1y, *self._near[0], *self._near[1],
            *(v for b in self.table.boxes for v in (b.x1, b.x2, b.y1, b.y2)),
            *self._hand.ravel().tolist(),
            line.y, below, -p.late_switch_lead if below else p.late_switch_lead,
        ]

    def _advance_steps(self, t: float, dt: float) -> None:
        """`advance` on two boxes: `compiled.person_steps`, as Python or compiled.

        Python pops the arm sightings (`_arm_seen`'s queue) when the steps stop for one; the
        state goes in and out through a vector (a list as Python, an array compiled).
        """
        c = self._consts
        if c is None:
            c = self._constants()
            if self._compiled:
                c = np.array(c, dtype=np.float64)
            self._consts = c
        assert len(c) == C_SIZE
        state = self._state
        state[:] = (
            self.t, self.z_h, self._x, self._y, self._vx, self._vy, _index(self._last_box),
            _index(self._arm_box), self._opposed, _index(self._first), _index(self._heading),
            self.switches, self._quick, -1, self._feint,
        )
        steps, seen, delay = self._steps, self._robot_seen, self.p.perception_delay_s
        while True:
            event = steps(t, dt, state, c, seen[0][0] if seen else math.inf)
            if event == SEEN:  # `_arm_seen`'s pop, at the same step's start
                cutoff = float(state[S_T]) - delay
                while seen and seen[0][0] <= cutoff:
                    self._last_box = seen.popleft()[1]
                state[S_LAST] = _index(self._last_box)
                continue
            v = state.tolist() if isinstance(state, np.ndarray) else state
            self._unpack(v)
            if v[S_PRESSED] >= 0:
                self.pressed = self._labels[int(v[S_PRESSED])]
            return

    def _unpack(self, v: list[float]) -> None:
        """The person's attributes from `compiled.person_steps`' state vector."""
        self.t, self.z_h, self._x, self._y, self._vx, self._vy = v[:6]
        self._arm_box, self._opposed, self._first = _box(v[7]), v[8] != 0.0, _box(v[9])
        self._heading, self.switches = _box(v[10]), int(v[11])
        self._quick, self._feint = v[S_QUICK] != 0.0, v[S_FEINT] != 0.0

    def _step(self, h: float) -> None:
        """One step of h on two boxes: eq 2 on the scalar x (`_arm_seen`), then the hand (`_move`).

        The step as the model states it, one call a step: `advance` takes these steps fused
        (`compiled.person_steps`), and tests/unit/test_loop_speed.py holds whole sessions of
        the two to the same bits.
        """
        if self.pressed is not None:
            return
        a = self.p.agent
        box, weight = self._arm_seen()
        r_hat = 0.0 if box is None else weight if box == 0 else -weight  # r̂: > 0 toward red

        # One RK4 step (`rk4_step`) of eq 2 with the robot's perceived heading r̂ as z_r,
        # a_hr = 1: `opinion_rate` written out (`compiled.eq2_step`: the same float operations
        # in the same order, tests/unit/test_loop_speed.py checks it), γ_h r̂ held.
        z = self.z_h = eq2_step(self.z_h, h, -a.d, a.u, a.alpha, a.gamma * r_hat, self.b_h)

        if self.t_go is None or self.t < self.t_go + self.p.reaction_s:  # (set: `advance`)
            return
        self._move(h, 0 if z > 0 else 1, abs(z))

    def _step_general(self, h: float) -> None:
        """One step of h on N_o boxes: eq 2 over options (RK4, r̂ held), then the hand.

        r̂ = option_vector(the arm's box) times its weight; the RK4 combination is the kernel's,
        term for term, so on two boxes x = z_0 comes out bit for bit as `_step`'s (tanh is odd,
        so F_1 = −F_0 and their mean is 0). The last option is set to minus the others' sum
        (`dynamics.on_subspace`). The hand heads for the leading option, its conviction the lead
        over the runner-up (|x| on two boxes).
        """
        if self.pressed is not None:
            return
        a = self.p.agent
        box, weight = self._arm_seen()
        n = self.n
        social = [0.0] * n if box is None else [weight * v for v in self._vectors[box]]
        z, b = self._z, self._b
        d, u, alpha, gamma = a.d, a.u, a.alpha, a.gamma
        hh = 0.5 * h
        k1 = float_rates(z, social, b, d, u, alpha, gamma)
        k2 = float_rates([x + hh * k for x, k in zip(z, k1, strict=True)],
                         social, b, d, u, alpha, gamma)
        k3 = float_rates([x + hh * k for x, k in zip(z, k2, strict=True)],
                         social, b, d, u, alpha, gamma)
        k4 = float_rates([x + h * k for x, k in zip(z, k3, strict=True)],
                         social, b, d, u, alpha, gamma)
        h6 = h / 6.0
        z = [x + h6 * (q1 + 2.0 * q2 + 2.0 * q3 + q4)
             for x, q1, q2, q3, q4 in zip(z, k1, k2, k3, k4, strict=True)]
        z[-1] = -sum(z[:-1])
        self._z = z
        self.z_h = z[0]

        if self.t_go is None or self.t < self.t_go + self.p.reaction_s:
            return
        top = max(z)
        wanted = z.index(top) if z.count(top) == 1 else None  # a tie leads nowhere
        self._move(h, wanted, 0.5 * (top - sorted(z)[-2]))

    def _move(self, h: float, wanted: int | None, lead: float) -> None:
        """The hand for one step of h, the opinion leading toward box `wanted` by `lead`.

        Heads for the wanted box (the first once chosen, a switch after, none when committed);
        a feint keeps to its first box until `_turn_at_the_line`. Speed: conviction = lead /
        full_conviction within [min_conviction, 1], or 1 straight on (committed, a feint).
        """
        p = self.p
        x, y = self._x, self._y
        heading = self._heading
        committed = heading is not None and (
            self._quick
            or self.switches >= self._max_switches
            or (
                self._obeys_commit
                and (y < self._commit_y if self._commit_below else y > self._commit_y)
            )
        )
        if heading is None:
            if wanted is None:
                return
            heading = self._heading = self._first = wanted
        elif self._feint:
            self._turn_at_the_line()
            heading = self._heading
            assert heading is not None  # set above on the first step after the reaction time
        elif wanted is not None and wanted != heading and not committed:
            heading = self._heading = wanted
            self.switches += 1
        tx, ty = self._centers[heading]
        dx, dy = tx - x, ty - y
        dist = math.hypot(dx, dy)
        if committed or self._feint:
            conviction = 1.0  # a committed hand (or a feint) goes straight on
        else:  # min(1, max(min_conviction, lead / full_conviction)), without the calls
            conviction = lead / p.full_conviction
            if not conviction > p.min_conviction:
                conviction = p.min_conviction
            if not conviction < 1.0:
                conviction = 1.0
        speed = p.speed * (p.late_switch_speed if self._quick else 1.0)
        gain = speed * conviction / (1e-9 if dist < 1e-9 else dist)  # / max(dist, 1e-9)
        vx, vy = self._vx, self._vy
        ax, ay = dx * gain - vx, dy * gain - vy
        dv = math.hypot(ax, ay)
        max_dv = p.accel * h
        if dv > max_dv:
            ax, ay = ax * max_dv / dv, ay * max_dv / dv
        vx, vy = self._vx, self._vy = vx + ax, vy + ay
        x, y = self._x, self._y = x + vx * h, y + vy * h
        for x1, x2, y1, y2 in self._near:  # `_press_test`, its cheap part inline
            if x1 <= x <= x2 and y1 <= y <= y2:
                self.pressed = self._press_test()
                return

    def _turn_at_the_line(self) -> None:
        """The feint's end: within `late_switch_lead` of the commit line, turn toward the arm.

        Decided once, at the line: if the arm is not seen at another box, keep going.
        """
        line = self.table.commit
        ahead = -self.p.late_switch_lead if line.start_side == "below" else self.p.late_switch_lead
        if not line.crossed((self._x, self._y + ahead)):
            return
        self._feint = False
        arm = self._arm_box
        if arm is not None and arm != self._heading:
            self._heading = arm
            self.switches += 1
            self._quick = True

    def _press_test(self) -> Opt | None:
        """A landmark of the (noise-free) hand inside a box; cheap when far from every box."""
        x, y = self._x, self._y
        for x1, x2, y1, y2 in self._near:
            if x1 <= x <= x2 and y1 <= y <= y2:
                pts = [(float(x), float(y)) for x, y in self.landmarks(noise=False)]
                box = self.table.pressed(pts)
                return None if box is None else self._labels[box]
        return None

    @property
    def heading(self) -> Opt | None:
        """The box the hand heads for (None before it moves)."""
        return None if self._heading is None else self._labels[self._heading]

    @property
    def opinion(self) -> np.ndarray:
        """z_h over the boxes (Σ = 0): on the kernel's two boxes (x, −x)."""
        return np.array(self._z if self.general else (self.z_h, -self.z_h))

    @property
    def pos(self) -> np.ndarray:
        """The hand centre (x, y)."""
        return np.array((self._x, self._y))

    # -- what the camera sees ---------------------------------------------------------------

    def landmarks(self, noise: bool = True) -> np.ndarray:
        """21 landmarks (x, y) around the hand centre, with camera noise when asked."""
        camera = self._camera
        if noise and camera is not None:  # the same draws and values, one call (`use_compiled`)
            pts = np.empty_like(self._hand)
            camera(self._hand, self._x, self._y, self.rng.standard_normal(self._hand.size + 2),
                   self.p.common_noise, self.p.landmark_noise, pts)
            return pts
        pts = self._hand + (self._x, self._y)  # a new array: updated in place below
        if noise:
            rng = self.rng
            pts += rng.normal(0.0, self.p.common_noise, 2)
            pts += rng.normal(0.0, self.p.landmark_noise, pts.shape)
        return pts.clip(0.0, 1.0, out=pts)

    def unseen(self) -> None:
        """A camera frame whose landmarks nobody reads: only its noise is drawn.

        The random stream goes on exactly as `landmarks` takes it (the same standard normals,
        one per coordinate, in the same order: `normal(0, s)` is 0 + s × a standard normal),
        so later draws are unchanged; the landmarks themselves are not made.
        """
        self.rng.standard_normal(2 + self._hand.size)


def _index(box: int | None) -> int:
    """A box for the compiled steps' state vector: −1 for None."""
    return -1 if box is None else box


def _box(v: float) -> int | None:
    """A box from the compiled steps' state vector."""
    return None if v < 0 else int(v)


def late_switch_chance(first: float, learn: float, opposed_trials: int) -> float:
    """A strategist's chance of playing the late switch in a control trial.

    `first` before any opposition; each control trial in which the arm headed against their
    first choice removes the share `learn` of the remaining doubt: 1 − (1 − first)(1 − learn)^n.
    """
    return 1.0 - (1.0 - first) * (1.0 - learn) ** opposed_trials


def jittered(base: ParticipantParams, rng: np.random.Generator) -> ParticipantParams:
    """One member of a cohort: the base traits with person-to-person variation."""
    from dataclasses import replace

    return replace(
        base,
        preference_mean=max(0.5, rng.normal(base.preference_mean, base.preference_spread)),
        trust0=max(0.1, rng.normal(base.trust0, 0.25)),
        gaze_gain=base.gaze_gain * math.exp(rng.normal(0.0, base.gaze_gain_spread)),
        reaction_s=max(0.1, rng.normal(base.reaction_s, 0.06)),
        speed=max(0.2, rng.normal(base.speed, 0.06)),
        perception_delay_s=max(0.1, rng.normal(base.perception_delay_s, 0.05)),
    )
