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
  predicted chance of C on O (agreement on O without the person switching). Control trials
  keep the paper's settings: they are where the person is observed.

`PolicyRun` is one session's use of a policy: its history, the operator's freeze (a frozen
policy keeps its last settings for the remaining trials) and the envelope. Pure: no files, no
clocks; the command line loads a policy file (`services.cohort.policy_file`).
"""

from __future__ import annotations

import math
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
    """Simulated people's outcomes of one trial under one setting, for one kind."""

    outcomes: tuple[int, ...]  # per `OUTCOMES`
    c_on_o: int  # of them C with the person on O

    @property
    def n(self) -> int:
        """How many simulated trials."""
        return sum(self.outcomes)


TableKey: TypeAlias = tuple[PolicySettings, int]  # (the trial's settings, the trial's index)


@dataclass(frozen=True)
class OutcomeTable:
    """Simulated people's outcomes per (settings, trial) and kind, and the kinds' shares.

    Built by `services.cohort.policy_table` from sessions each of which kept one candidate
    setting for every consensus trial (the paper's in the control trials).
    """

    candidates: tuple[PolicySettings, ...]
    prior: Mapping[Kind, int]  # simulated people of each kind
    cells: Mapping[TableKey, Mapping[Kind, Counts]] = field(default_factory=dict)

    def likelihood(self, played: Played, kind: Kind) -> float | None:
        """P(this trial's outcome | kind, its settings), smoothed; None: the table has no cell."""
        cell = self.cells.get((played.settings, played.trial))
        if cell is None or kind not in cell:
            return None
        c = cell[kind]
        return (c.outcomes[OUTCOMES.index(played.label)] + 0.5) / (c.n + 0.5 * len(OUTCOMES))

    def posterior(self, history: Sequence[Played]) -> dict[Kind, float]:
        """P(kind | the outcomes so far): the table's shares times each trial's likelihood.

        Trials are taken as independent given the kind (the person's learning is in the
        table's cells only through the trial's index): an approximation, stated in
        docs/adaptive.md. A trial whose settings the table lacks gives no evidence.
        """
        total = sum(self.prior.values())
        logp = {k: math.log((self.prior.get(k, 0) + 0.5) / (total + 0.5 * len(KINDS)))
                for k in KINDS}
        for played in history:
            lik = {k: self.likelihood(played, k) for k in KINDS}
            if any(v is None for v in lik.values()):
                continue
            for k in KINDS:
                logp[k] += math.log(lik[k])  # type: ignore[arg-type]
        top = max(logp.values())
        w = {k: math.exp(v - top) for k, v in logp.items()}
        s = sum(w.values())
        return {k: v / s for k, v in w.items()}

    def chance_c(self, s: PolicySettings, trial: int, kind: Kind) -> float:
        """P(C on O | kind, settings, trial), Beta(1, 1)-smoothed (0.5 for an empty cell)."""
        c = self.cells.get((s, trial), {}).get(kind)
        return 0.5 if c is None else (c.c_on_o + 1) / (c.n + 2)


@dataclass(frozen=True)
class AdaptivePolicy:
    """The expected-value rule over the simulated person (module doc)."""

    table: OutcomeTable
    name: str = "adaptive"

    def choose(
        self, spec: TrialSpec, paper: PolicySettings, history: Sequence[Played]
    ) -> PolicySettings:
        """The paper's in a control trial, else the candidate likeliest to give C on O."""
        if spec.mode != "consensus" or not self.table.candidates:
            return paper
        post = self.table.posterior(history)
        return max(
            self.table.candidates,
            key=lambda s: sum(p * self.table.chance_c(s, spec.index, k) for k, p in post.items()),
        )


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
