"""`nod replay --through decision --policy P`: what a robot policy would have done, offline.

A counterfactual on a recorded person's motion, in two passes over the recording:

1. **The session, played by the policy.** The recorded hand (each trial's poses, timed from
   its "go": `services.recording.reaches`) drives the offline loop (`run_offline_session`, the
   decision model, Algorithm 2 with the simulated arm and the trial judge of the live services)
   with the policy in a `PolicyRun` inside the recording's `[policy]` envelope. Before each
   trial the policy chooses b*, the gaze level and u_r from the trials played so far, and the
   loop hands it each trial's own counterfactual outcome (`Played`: the robot's press under
   the policy against the recorded person's press and switches).
2. **The derived recording.** `through_decision` re-runs the decision model over the recorded
   poses as without a policy, each trial retuned to the b* and u_r the policy chose for it
   (`decision_for`; the paper's settings leave the engine as it is, so `--policy paper` writes
   the file `--through decision` writes without one).

What it cannot do, said in its output: the recorded person saw the recorded gaze and the
recorded robot. The gaze level the policy would have chosen is reported and marked "not
applied"; and the person's motion (so their press and their switches) is held to what they
did, although they might have moved otherwise beside another robot. The loop reads the
recorded poses on its own 30 Hz frames (the derived file on the poses' stamps), so the
robot's press and the recomputed z_r can differ on a trial decided at a hair.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from services.cohort.person import load_cohort_params
from services.cohort.policy_file import PolicyFile, make_policy, read_policy_file
from services.cohort.policy_table import TableJob, TableRow
from services.core import messages as m
from services.core.keys import topic_of
from services.model.closed_loop import OfflineTrial, run_offline_session
from services.model.decision import DecisionParams
from services.model.params import NodConfig
from services.model.policy import PolicyRun, PolicySettings, decision_for, paper_settings
from services.recording.mcap_io import McapIn
from services.recording.reaches import recorded_hands
from services.recording.selection import decode_entry
from services.recording.through import (
    ThroughResult,
    TrialComparison,
    decision_config,
    paper_options,
    through_decision,
)

GAZE_NOT_APPLIED = ("the gaze level is the policy's choice, NOT applied: the recorded person "
                    "saw the recorded gaze (and the recorded robot), and their motion is "
                    "replayed as it was")


@dataclass(frozen=True)
class PolicyTrial:
    """One recorded trial under the policy, beside what happened."""

    trial: int
    mode: str
    option: str | None
    settings: PolicySettings  # the policy's (inside the envelope); its gaze level not applied
    paper: PolicySettings  # the recording's own b*, u_r and scheduled gaze level
    gaze_recorded: str | None  # the level the recorded eyes showed (None: not recorded)
    robot: str | None  # the counterfactual robot's press (the offline loop)
    human: str | None  # the person's press, judged from their recorded motion
    outcome: str | None  # the counterfactual trial's label (C, CH, D, DH; None: no verdict)
    z_r_at_press: float | None  # the recomputed z_r at the pose of the human's press
    recorded_z_r_at_press: float | None
    recorded_robot: str | None
    recorded_human: str | None
    recorded_outcome: str | None

    def as_json(self) -> dict[str, Any]:
        """The trial as `--json` writes it."""
        s, p = self.settings, self.paper
        return {
            "trial": self.trial, "mode": self.mode, "option": self.option,
            "policy": {"b_star": s.b_star, "u_r": s.u_r, "gaze_level": s.gaze_level,
                       "gaze_applied": False},
            "paper": {"b_star": p.b_star, "u_r": p.u_r, "gaze_level": p.gaze_level},
            "gaze_recorded": self.gaze_recorded,
            "would": {"robot": self.robot, "human": self.human, "outcome": self.outcome,
                      "z_r_at_press": self.z_r_at_press},
            "recorded": {"robot": self.recorded_robot, "human": self.recorded_human,
                         "outcome": self.recorded_outcome,
                         "z_r_at_press": self.recorded_z_r_at_press},
        }

    def line(self) -> str:
        """`policy trial 4 consensus O=red: b* 6.00 u_r 2.24 gaze extreme (not applied; ...`."""
        s = self.settings
        shown = self.gaze_recorded or self.paper.gaze_level

        def z(v: float | None) -> str:
            return "—" if v is None else f"{v:+.3f}"

        option = f" O={self.option}" if self.option else ""
        return (
            f"policy trial {self.trial} {self.mode}{option}: b* {s.b_star:.2f} u_r {s.u_r:.2f} "
            f"gaze {s.gaze_level} (not applied; shown: {shown})"
            f"; would: robot {self.robot or '—'}, outcome {self.outcome or '—'}, z_r at the "
            f"human's press {z(self.z_r_at_press)}; recorded: robot {self.recorded_robot or '—'},"
            f" human {self.recorded_human or '—'}, outcome {self.recorded_outcome or '—'}, z_r "
            f"{z(self.recorded_z_r_at_press)}"
        )


@dataclass(frozen=True)
class PolicyReplay:
    """What `--through decision --policy` did."""

    policy: PolicyFile
    through: ThroughResult
    trials: list[PolicyTrial]

    def as_json(self) -> dict[str, Any]:
        """The summary as `--json` writes it."""
        return {
            "policy": {"name": self.policy.name, "sha256": self.policy.sha256,
                       "kind": self.policy.kind},
            "counterfactual": True,
            "gaze_applied": False,
            "limits": GAZE_NOT_APPLIED,
            "trials": [t.as_json() for t in self.trials],
            "messages": self.through.messages,
            "poses": self.through.poses,
            "recomputed": self.through.recomputed,
            "left_out": self.through.left_out,
        }


def load_policy(arg: str, cfg: NodConfig, policy_params: Path | None) -> tuple[PolicyFile,
                                                                                PolicyRun]:
    """The policy of `--policy` on the recording's configuration, in its envelope.

    An adaptive policy's table is simulated from `policy_params`' people (default: the fitted
    person, `nod cohort`'s, so the cohort's cached table serves); its candidates must lie in
    the recording's envelope too. ValueError (one line) for a bad file.
    """
    pf = read_policy_file(arg)
    built_on = load_cohort_params(policy_params)
    if pf.kind == "paper":
        return pf, PolicyRun(make_policy(pf, built_on), cfg.policy)
    pf.candidates(cfg)  # refuse a candidate outside the recording's envelope
    with ProcessPoolExecutor() as pool:  # the table's people on every core, if not cached

        def mapper(fn: Callable[[TableJob], TableRow], jobs: Sequence[TableJob]
                   ) -> Iterable[TableRow]:
            return pool.map(fn, jobs, chunksize=8)

        return pf, PolicyRun(make_policy(pf, built_on, mapper), cfg.policy)


def played_session(src: Path, cfg: NodConfig, run: PolicyRun) -> list[OfflineTrial[Any]]:
    """The recorded hand through the offline loop with the policy (pass 1 of the module doc).

    The session runs the recording's trials: its parameters' protocol, cut to the trials the
    recording holds a hand path for (a session stopped early), which must be its first ones.
    """
    hands = recorded_hands(src)
    if not hands:
        raise ValueError(f"{src} has no trial with a \"go\" and hand poses: nothing to replay "
                         "the policy on")
    specs = cfg.protocol.trials
    indices = sorted(hands)
    if indices != list(range(1, len(indices) + 1)) or len(indices) > len(specs):
        raise ValueError(f"{src}: the policy replays the protocol's trials from the first; the "
                         f"recording has hand paths for trials {indices} of {len(specs)}")
    cut = replace(cfg, protocol=replace(cfg.protocol, trials=specs[: len(indices)]))
    events = recorded_setups(src)
    for spec in cut.protocol.trials:
        was = events.get(spec.index)
        if was is not None and was != (spec.mode, spec.option):
            raise ValueError(
                f"{src}: trial {spec.index} was recorded as {was[0]} O={was[1]}, its parameters' "
                f"protocol says {spec.mode} O={spec.option}: the policy replays the protocol's "
                "trials (give the session's parameters with --params)")
    trials: list[OfflineTrial[Any]] = run_offline_session(cut, 0, hands=hands, policy=run)
    return trials


def recorded_setups(src: Path) -> dict[int, tuple[str, str | None]]:
    """Each recorded trial's (mode, O), from its last "setup" event."""
    out: dict[int, tuple[str, str | None]] = {}
    for e in McapIn(src):
        if topic_of(e.key) != "experiment/trial" or not e.valid:
            continue
        msg = decode_entry("experiment/trial", e)
        if isinstance(msg, m.TrialEvent) and msg.phase == "setup":
            paper_options(msg, src)  # a recording of N options: refused as --through refuses it
            out[msg.trial] = (msg.mode, msg.option)
    return out


def tuning(cfg: NodConfig, trials: Sequence[OfflineTrial[Any]]) -> dict[int, DecisionParams]:
    """Each trial's decision parameters under its policy settings (the paper's: the config's)."""
    out: dict[int, DecisionParams] = {}
    for t in trials:
        if t.settings is None:
            continue
        paper = paper_settings(cfg.decision, cfg.protocol.trials[t.trial - 1])
        out[t.trial] = cfg.decision if t.settings == paper else decision_for(cfg.decision,
                                                                              t.settings)
    return out


def replay_policy(
    src: Path,
    out: Path,
    params: Path | None,
    policy: str,
    policy_params: Path | None = None,
) -> PolicyReplay:
    """`nod replay SRC --through decision [--params P] --policy POLICY --out OUT`."""
    cfg = decision_config(McapIn(src).file_metadata(), params)
    pf, run = load_policy(policy, cfg, policy_params)
    played = played_session(src, cfg, run)
    chosen = {t.trial: t.settings for t in played if t.settings is not None}
    meta = {
        "through_policy": pf.name,
        "through_policy_sha256": pf.sha256,
        "through_policy_kind": pf.kind,
        "through_policy_gaze": "not applied: the recorded person saw the recorded gaze; the "
                               "levels in through_policy_settings are the policy's choice",
        "through_policy_settings": json.dumps(
            {str(k): {"b_star": s.b_star, "u_r": s.u_r, "gaze_level": s.gaze_level}
             for k, s in sorted(chosen.items())}),
    }
    if policy_params is not None:
        meta["through_policy_params_file"] = str(policy_params)
    res = through_decision(src, out, params, tuning(cfg, played), meta)
    recorded = {t.trial: t for t in res.trials}
    trials = [_trial(cfg, t, recorded.get(t.trial)) for t in played if t.settings is not None]
    return PolicyReplay(pf, res, trials)


def _trial(cfg: NodConfig, t: OfflineTrial[Any], rec: TrialComparison | None) -> PolicyTrial:
    assert t.settings is not None  # the loop ran with a policy
    spec = cfg.protocol.trials[t.trial - 1]
    was, now = rec.at_press() if rec is not None else (None, None)
    return PolicyTrial(
        trial=t.trial, mode=t.mode, option=t.option, settings=t.settings,
        paper=paper_settings(cfg.decision, spec),
        gaze_recorded=rec.gaze if rec is not None else None,
        robot=t.robot, human=t.human, outcome=t.outcome,
        z_r_at_press=_z(now),
        recorded_z_r_at_press=_z(was),
        recorded_robot=rec.robot if rec else None,
        recorded_human=rec.human if rec else None,
        recorded_outcome=rec.outcome if rec else None,
    )


def _z(v: tuple[float, float] | None) -> float | None:
    return None if v is None or math.isnan(v[0]) else v[0]
