"""The conductor's side of the robot policy: each trial's settings chosen, sent, stored.

Before each trial begins (the protocol's planner, `SessionProtocol(planner=…)`, the same hook
the offline loop uses) the session's `PolicyRun` chooses the trial's b*, gaze level and u_r
inside the params file's envelope (`services.model.policy`). The settings go out on
`experiment/policy` before the trial's setup and again at its "go" (a decision service
restarted in between still runs the trial on them), and into the store with the session's
policy (`services.store.policies`). The gaze level reaches the eyes as the trial's gaze
command (always toward O or straight ahead). After each stored trial the policy sees its
outcome; the operator's freeze (`nod experiment freeze`) keeps the last settings for the rest of
the session, and is confirmed on the key (`frozen`) only once it holds.

A resumed session's policy starts from the trials stored before (their settings and outcomes),
so it chooses as it would have, had the conductor not stopped.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from services.core.node import Node
from services.model.params import NodConfig
from services.model.policy import (
    Played,
    PolicyRun,
    PolicySettings,
    paper_settings,
    spec_for,
)
from services.model.schedule import Mode, TrialSpec
from services.store import Store, TrialRecord
from services.store.policies import begin_policy, read_policies, write_policy_trial

log = logging.getLogger("nod.experiment")


@dataclass(frozen=True, slots=True)
class PolicyChoice:
    """The policy a session runs: its run (policy, envelope), its name and file's SHA-256."""

    run: PolicyRun
    name: str
    sha256: str


class PolicyLink:
    """Chooses, sends and stores each trial's settings; feeds the policy each outcome."""

    def __init__(self, node: Node, cfg: NodConfig, store: Store, choice: PolicyChoice) -> None:
        self.cfg, self.store, self.choice = cfg, store, choice
        self.run = choice.run
        self.pub = node.publisher("experiment/policy")
        self.session = ""
        self.settings: dict[int, PolicySettings] = {}  # chosen, by trial
        self._unstored: list[int] = []  # chosen under the node's lock, stored on the main thread

    def begin(self, session: str, stored: list[TrialRecord]) -> None:
        """A session starts (or resumes after `stored`): its policy on record, its history."""
        self.session = session
        begin_policy(self.store, session, self.choice.name, self.choice.sha256)
        before = read_policies(self.store).get(session)  # a resume: `resume_problem` held it
        kept = before.trials if before is not None else {}
        for record in stored:
            if record.trial in kept:
                self.played(record, kept[record.trial])

    def plan(self, spec: TrialSpec) -> TrialSpec:
        """The protocol's planner: the trial with the policy's settings (sent at once)."""
        s = self.run.settings(spec, paper_settings(self.cfg.decision, spec))
        self.settings[spec.index] = s
        self._unstored.append(spec.index)
        self.send(spec.index)
        return spec_for(spec, s)

    def send(self, trial: int) -> None:
        """Publish a trial's settings (before its setup, at its go, on a freeze)."""
        s = self.settings.get(trial)
        if s is None:
            return
        self.pub.put(session=self.session, trial=trial, policy=self.choice.name,
                     sha256=self.choice.sha256, b_star=s.b_star, gaze_level=s.gaze_level,
                     u_r=s.u_r, frozen=self.run.frozen)

    def store_chosen(self) -> None:
        """Store the settings chosen since the last call (main thread: the store's writer)."""
        while self._unstored:
            trial = self._unstored.pop(0)
            write_policy_trial(self.store, self.session, trial, self.settings[trial])

    def ended(self, record: TrialRecord) -> None:
        """A trial was stored: the policy sees its outcome before choosing the next one."""
        s = self.settings.get(record.trial)
        if s is not None:  # an interrupted one too (no outcome), as the offline loop tells it
            self.played(record, s)

    def played(self, record: TrialRecord, s: PolicySettings) -> None:
        """Tell the policy how a trial played on settings `s`."""
        mode: Mode = "consensus" if record.mode == "consensus" else "dissensus"
        self.run.played(Played.of(record.trial, mode, s, record.outcome, record.option,
                                  record.human))

    def freeze(self, source: str) -> None:
        """The operator's freeze: the last settings hold from now on (confirmed on the key)."""
        if not self.run.frozen:
            log.warning("robot policy %s frozen by %s", self.choice.name, source or "the operator")
        self.run.freeze()
        if self.settings:
            self.send(max(self.settings))


def load_choice(arg: str, cfg: NodConfig) -> PolicyChoice:
    """`--policy paper|adaptive|FILE.toml` on this configuration (ValueError: one line).

    An adaptive policy's table is read from its cache, or built once (a local compute engine,
    opened only then) and cached.
    """
    from services.cohort.policy_file import make_policy, read_policy_file

    pf = read_policy_file(arg)

    def on_an_engine(fn: Callable[[Any], Any], jobs: Sequence[Any]) -> Iterator[Any]:
        from services.compute.engine import open_engine

        log.info("building the %s policy's table of %d simulated people (cached after)",
                 pf.name, len(jobs))
        with open_engine() as engine:
            yield from engine.map(fn, jobs)

    policy = make_policy(pf, cfg, on_an_engine)
    return PolicyChoice(PolicyRun(policy, cfg.policy), pf.name, pf.sha256)


def resume_problem(store: Store, session: str, choice: PolicyChoice | None) -> str | None:
    """Why `session` cannot resume under `choice` (None: it can): a session keeps its policy."""
    before = read_policies(store).get(session)
    if before is None:
        return None if choice is None else (
            f"session {session} ran without a robot policy: resume it without --policy")
    if choice is None or (before.policy, before.sha256) != (choice.name, choice.sha256):
        return (f"session {session} ran the robot policy {before.policy} "
                f"(sha256 {before.sha256[:12]}): resume it with --policy {before.policy}")
    return None
