"""The robot's policy: the settings the paper fixed for everyone, chosen before each trial.

A policy chooses, before each trial, a `PolicySettings`: the bias threshold b* (eq 6), the
trial's gaze level (one of the schedule's levels, turned toward the trial's O: the eyes only
ever look at O or straight ahead) and the robot's attention u_r (eq 1). Whatever it chooses
passes through the `Envelope` the params file declares (`[policy]`, `NodConfig.policy`), so no
policy's settings leave it (tests/unit/test_policy.py, a property test).

Two policies, one idea each:

- `PaperPolicy`: today's robot, exactly: each trial's settings are the schedule's gaze level
  and the configured b* and u_r (`paper_settings`). The default everywhere.
- `AdaptivePolicy`: an expected-value rule over the simulated person. Before a consensus trial
  it infers which kind of person this is (`KINDS`: strategist, contrarian, firm, the rest) from
  the outcomes so far, as a posterior against an `OutcomeTable` of simulated people (built once,
  seeded, by `services.cohort.policy_table`), and picks the candidate setting with the best
  predicted chance of C on O (agreement on O without the person switching), optionally plus a
  weight on agreement on O. Control trials keep the paper's settings: they are where the
  person is observed.
- `ExplorePolicy`: a candidate at random per consensus trial (seeded): how the table's
  simulated people are run, so every cell of it is visited.

`PolicyRun` is one session's use of a policy: its history, the operator's freeze (a frozen
policy keeps its last settings for the remaining trials) and the envelope. Pure: no files, no
clocks; the command line loads a policy file (`services.cohort.policy_file`).
"""

from __future__ import annotations

import math
import random
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal, Protocol, TypeAlias

from services.model.decision import DecisionParams
from services.model.gaze import GAZE_LEVEL_NAMES, GazeLevelName
from services.model.schedule import Mode, TrialSpec

Kind: TypeAlias = Literal["strategist", "contrarian", "firm", "rest"]
KINDS: tuple[Kind, ...] = ("strategist", "contrarian", "firm", "rest")
OUTCOMES: tuple[str, ...] = ("C", "CH", "D", "DH", "none")  # a trial's label; none: no verdict


def kind_of(strategist: bool, contrarian: bool, firm: bool) -> Kind:
    """The kind of a simulated person from its drawn traits (`Participant`).

    Firm before contrarian before strategist: a contrarian's distrust of the eyes acts in the
    consensus trials, where the policy acts; a strategist's late switch only in control trials.
    """
    if firm:
        return "firm"
    if contrarian:
        return "contrarian"
    return "strategist" if strategist else "rest"


@dataclass(frozen=True, slots=True)
class PolicySettings:
    """The robot's settings for one trial."""

    b_star: float  # eq 6's bias threshold b*
    gaze_level: GazeLevelName  # toward the trial's O (neutral: straight ahead)
    u_r: float  # eq 1's attention u_r

    def __post_init__(self) -> None:
        if not (math.isfinite(self.b_star) and math.isfinite(self.u_r)):
            raise ValueError(f"policy settings must be finite, got b*={self.b_star}, "
                             f"u_r={self.u_r}")
        if self.gaze_level not in GAZE_LEVEL_NAMES:
            raise ValueError(f"unknown gaze level {self.gaze_level!r}; expected one of "
                             f"{GAZE_LEVEL_NAMES}")


@dataclass(frozen=True, slots=True)
class Envelope:
    """The `[policy]` table: the bounds no policy's settings leave (they hold the paper's)."""

    b_star: tuple[float, float] = (3.0, 6.0)  # [low, high] of b*; the paper's robot: 4.54
    u_r: tuple[float, float] = (1.5, 3.0)  # [low, high] of u_r; the paper's: 2.24
    gaze_levels: tuple[GazeLevelName, ...] = GAZE_LEVEL_NAMES  # the levels a policy may use

    def __post_init__(self) -> None:
        for name in ("b_star", "u_r"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
                raise ValueError(f"[policy] {name} must be [low, high] with 0 < low <= high, "
                                 f"got {[lo, hi]}")
        bad = [g for g in self.gaze_levels if g not in GAZE_LEVEL_NAMES]
        if not self.gaze_levels or bad:
            raise ValueError(f"[policy] gaze_levels must be some of {GAZE_LEVEL_NAMES}, "
                             f"got {list(self.gaze_levels)}")

    def contains(self, s: PolicySettings) -> bool:
        """Whether settings lie inside the envelope."""
        return (self.b_star[0] <= s.b_star <= self.b_star[1]
                and self.u_r[0] <= s.u_r <= self.u_r[1] and s.gaze_level in self.gaze_levels)

    def clip(self, s: PolicySettings) -> PolicySettings:
        """The settings inside the envelope: numbers clamped, a level the nearest allowed one.

        Nearest by the levels' rising order; a tie goes to the weaker level (the eyes guide
        less, never more, than asked).
        """
        if self.contains(s):
            return s
        rank = GAZE_LEVEL_NAMES.index

        def distance(g: GazeLevelName) -> tuple[int, int]:
            return abs(rank(g) - rank(s.gaze_level)), rank(g)

        level = min(self.gaze_levels, key=distance)
        return PolicySettings(
            min(max(s.b_star, self.b_star[0]), self.b_star[1]), level,
            min(max(s.u_r, self.u_r[0]), self.u_r[1]),
        )


def paper_settings(decision: DecisionParams, spec: TrialSpec) -> PolicySettings:
    """Today's settings for a trial: its scheduled gaze level, the configured b* and u_r."""
    u = decision.pair.robot.u
    level = spec.gaze_level
    assert level in GAZE_LEVEL_NAMES  # checked by TrialSpec
    return PolicySettings(decision.bias.threshold(u), level, u)


def decision_for(decision: DecisionParams, s: PolicySettings) -> DecisionParams:
    """The decision engine's parameters with a trial's b* and u_r."""
    pair = decision.pair
    return replace(decision, pair=replace(pair, robot=replace(pair.robot, u=s.u_r)),
                   bias=replace(decision.bias, b_star=s.b_star))


def spec_for(spec: TrialSpec, s: PolicySettings) -> TrialSpec:
    """The trial with the settings' gaze level, turned toward its O (itself if unchanged)."""
    if s.gaze_level == spec.gaze_level:
        return spec
    return replace(spec, gaze_level=s.gaze_level, yaw=None, pitch=None)


@dataclass(frozen=True, slots=True)
class Played:
    """One trial as a policy sees it afterwards."""

    trial: int
    mode: Mode
    settings: PolicySettings
    outcome: str | None  # C, CH, D, DH or None (no verdict)
    on_option: bool  # the person pressed the trial's O (consensus trials)

    @property
    def label(self) -> str:
        """The outcome as `OUTCOMES` names it."""
        return self.outcome if self.outcome in OUTCOMES else "none"

    @classmethod
    def of(cls, trial: int, mode: Mode, settings: PolicySettings, outcome: str | None,
           option: object, human: object) -> Played:
        """A judged trial: O and the person's press (`on_option`: they pressed O)."""
        return cls(trial, mode, settings, outcome, option is not None and human == option)


class Policy(Protocol):
    """Chooses a trial's settings from today's (`paper`) and the trials played so far."""

    @property
    def name(self) -> str:
        """The policy's name, stored with each session."""
        ...

    def choose(
        self, spec: TrialSpec, paper: PolicySettings, history: Sequence[Played]
    ) -> PolicySettings:
        """The settings of trial `spec`, before the envelope."""
        ...


@dataclass(frozen=True, slots=True)
class PaperPolicy:
    """The paper's robot: the same settings for everyone, the schedule's gaze."""

    name: str = "paper"

    def choose(
        self, spec: TrialSpec, paper: PolicySettings, history: Sequence[Played]
    ) -> PolicySettings:
        """Today's settings."""
        return paper


@dataclass(frozen=True, slots=True)
class Counts:
    """Simulated people's outcomes of one table cell, for one kind."""

    outcomes: tuple[int, ...]  # per `OUTCOMES`
    c_on_o: int  # of them C with the person on O
    agree_on_o: int = 0  # of them C or CH with the person on O

    @property
    def n(self) -> int:
        """How many simulated trials."""
        return sum(self.outcomes)


# A table cell: (the trial's settings, its index, how many consensus trials before it had a
# gaze cue). The last is the robot's own history, which a contrarian learns from.
TableKey: TypeAlias = tuple[PolicySettings, int, int]


def cued_before(history: Sequence[Played], trial: int) -> int:
    """How many consensus trials before `trial` the eyes gave a cue (a level not neutral)."""
    return sum(1 for p in history
               if p.trial < trial and p.mode == "consensus" and p.settings.gaze_level != "neutral")


@dataclass(frozen=True)
class OutcomeTable:
    """Simulated people's outcomes per cell (`TableKey`) and kind, and the kinds' counts.

    Built by `services.cohort.policy_table` from sessions whose consensus trials each drew a
    candidate setting at random (`ExplorePolicy`; the paper's in the control trials).
    """

    candidates: tuple[PolicySettings, ...]
    prior: Mapping[Kind, int]  # simulated people of each kind
    cells: Mapping[TableKey, Mapping[Kind, Counts]] = field(default_factory=dict)

    def likelihood(self, played: Played, cued: int, kind: Kind) -> float | None:
        """P(this trial's outcome | kind, its cell), smoothed; None: the table has no cell."""
        cell = self.cells.get((played.settings, played.trial, cued))
        if cell is None or kind not in cell:
            return None
        c = cell[kind]
        return (c.outcomes[OUTCOMES.index(played.label)] + 0.5) / (c.n + 0.5 * len(OUTCOMES))

    def posterior(self, history: Sequence[Played]) -> dict[Kind, float]:
        """P(kind | the outcomes so far): the table's shares times each trial's likelihood.

        Trials are taken as independent given the kind and the cell (the person's learning
        enters only through the cell's trial index and cues before): an approximation, stated
        in docs/adaptive.md. A trial whose cell the table lacks gives no evidence.
        """
        total = sum(self.prior.values())
        logp = {k: math.log((self.prior.get(k, 0) + 0.5) / (total + 0.5 * len(KINDS)))
                for k in KINDS}
        for played in history:
            cued = cued_before(history, played.trial)
            lik = [self.likelihood(played, cued, k) for k in KINDS]
            if any(v is None for v in lik):
                continue
            for k, v in zip(KINDS, lik, strict=True):
                logp[k] += math.log(v)  # type: ignore[arg-type]
        top = max(logp.values())
        w = {k: math.exp(v - top) for k, v in logp.items()}
        s = sum(w.values())
        return {k: v / s for k, v in w.items()}

    def chances(self, key: TableKey, kind: Kind) -> tuple[float, float]:
        """P(C on O), P(C or CH on O) in a cell for a kind, Beta(1, 1)-smoothed."""
        c = self.cells.get(key, {}).get(kind)
        if c is None:
            return 0.5, 0.5
        return (c.c_on_o + 1) / (c.n + 2), (c.agree_on_o + 1) / (c.n + 2)


@dataclass(frozen=True)
class AdaptivePolicy:
    """The expected-value rule over the simulated person (module doc).

    The value of a candidate in a cell is P(C on O) + agreement_weight · P(C or CH on O), the
    posterior's mixture over kinds (a weight above 0 guards agreement on O while seeking C).
    The rule looks ahead over the session's remaining consensus trials: a cue now changes
    the cells of the trials after it (a contrarian learns from the cues), so it takes the
    candidate that starts the best plan over them, by dynamic programming over (trial, cues
    so far), the posterior held at today's (`plan`).
    """

    table: OutcomeTable
    name: str = "adaptive"
    agreement_weight: float = 0.0

    def value(self, s: PolicySettings, trial: int, cued: int, post: Mapping[Kind, float]
              ) -> float:
        """The candidate's expected value in one trial for this person (the posterior)."""
        total = 0.0
        for k, p in post.items():
            c, agree = self.table.chances((s, trial, cued), k)
            total += p * (c + self.agreement_weight * agree)
        return total

    def plan(self, trial: int, cued: int, post: Mapping[Kind, float]
             ) -> tuple[float, PolicySettings]:
        """The best total value over the table's trials from `trial` on, and its first step."""
        trials = sorted({t for (_, t, _) in self.table.cells if t >= trial} | {trial})
        best: dict[tuple[int, int], tuple[float, PolicySettings]] = {}

        def go(i: int, c: int) -> float:
            if i == len(trials):
                return 0.0
            if (i, c) not in best:
                best[(i, c)] = max(
                    ((self.value(s, trials[i], c, post)
                      + go(i + 1, c + (s.gaze_level != "neutral")), s)
                     for s in self.table.candidates),
                    key=lambda vs: vs[0])
            return best[(i, c)][0]

        return go(0, cued), best[(0, cued)][1]

    def choose(
        self, spec: TrialSpec, paper: PolicySettings, history: Sequence[Played]
    ) -> PolicySettings:
        """The paper's in a control trial, else the first step of the best plan."""
        if spec.mode != "consensus" or not self.table.candidates:
            return paper
        post = self.table.posterior(history)
        return self.plan(spec.index, cued_before(history, spec.index), post)[1]


@dataclass(frozen=True)
class ExplorePolicy:
    """Each consensus trial a candidate drawn at random (seeded): how the table is simulated."""

    candidates: tuple[PolicySettings, ...]
    seed: int
    name: str = "explore"

    def choose(
        self, spec: TrialSpec, paper: PolicySettings, history: Sequence[Played]
    ) -> PolicySettings:
        """The paper's in a control trial, else a candidate drawn for (seed, trial)."""
        if spec.mode != "consensus" or not self.candidates:
            return paper
        return self.candidates[random.Random(f"{self.seed}:{spec.index}").randrange(
            len(self.candidates))]


class PolicyRun:
    """One session's use of a policy: its history, the envelope, the operator's freeze."""

    def __init__(self, policy: Policy, envelope: Envelope) -> None:
        self.policy = policy
        self.envelope = envelope
        self.history: list[Played] = []
        self.frozen = False
        self.last: PolicySettings | None = None

    def freeze(self) -> None:
        """The operator's freeze: the last settings stay for the remaining trials."""
        self.frozen = True

    def settings(self, spec: TrialSpec, paper: PolicySettings) -> PolicySettings:
        """The settings of the trial about to begin, inside the envelope."""
        if self.frozen and self.last is not None:
            return self.last
        self.last = self.envelope.clip(self.policy.choose(spec, paper, tuple(self.history)))
        return self.last

    def played(self, trial: Played) -> None:
        """A trial has ended: the policy sees it before the next one."""
        self.history.append(trial)
