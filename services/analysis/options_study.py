"""The study analysis over sessions of three or more options (`nod analyze options-study`).

The outcome classes C / CH / D / DH do not depend on the number of options, so the paper's
statistics generalise as they are: `services.analysis.study.analyze_study` runs on the
N_o-option sessions' outcomes (Fig 8a frequencies per trial, the control → experiment flows,
the Stuart-Maxwell tests with their correction; the questionnaire is not asked here). What
only N options have is added per trial (Fig 8-style shares over options):

- `human` / `robot`: how many participants' human and robot pressed each option;
- `both_on_o`: in a consensus trial, how many ended with both on O (the consensus claim);
- `robot_not_human`: in a control trial, how many robots pressed another box than the human.

Inclusion as `services.analysis.sessions`: complete sessions (status complete, every
scheduled trial stored), the latest per participant. The analysis needs the paper's 8-trial
structure (trials 1-3 dissensus, 4-8 consensus), which the default N_o-option schedule has;
another schedule is refused in one line. All sessions must share one option set.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from services.analysis.sessions import TRIALS, ExcludedSession, ParticipantOutcomes
from services.analysis.study import analyze_study
from services.model.phases import CONTROL_TRIALS
from services.store import Store
from services.store.options import OptionsStore, OptionsTrialRecord


def _schedule_modes(config: str | None) -> list[tuple[int, str]]:
    try:
        rows = json.loads(config or "{}")["option_schedule"]
        return [(int(r["index"]), str(r["mode"])) for r in rows]
    except (ValueError, KeyError, TypeError):
        return []


PAPER_MODES = [(t, "dissensus" if t in CONTROL_TRIALS else "consensus") for t in TRIALS]


def option_shares(
    names: Sequence[str], sessions: Sequence[Sequence[OptionsTrialRecord]]
) -> dict[str, dict[str, Any]]:
    """Per trial: each option's count among humans' and robots' presses, and the agreements."""
    out: dict[str, dict[str, Any]] = {}
    for trial in TRIALS:
        recs = [r for trials in sessions for r in trials if r.trial == trial]
        row: dict[str, Any] = {
            "n": len(recs),
            "human": {n: sum(r.human == j for r in recs) for j, n in enumerate(names)},
            "robot": {n: sum(r.robot == j for r in recs) for j, n in enumerate(names)},
        }
        row["human"]["none"] = sum(r.human is None for r in recs)
        if trial in CONTROL_TRIALS:
            row["robot_not_human"] = sum(
                r.robot is not None and r.human is not None and r.robot != r.human for r in recs
            )
        else:
            row["both_on_o"] = sum(r.human == r.option == r.robot for r in recs)
        out[str(trial)] = row
    return out


def analyze_options_study(path: str | Path) -> dict[str, Any]:
    """Every number of the N_o-option study of one store, as one JSON-ready document."""
    if not Path(path).is_file():
        raise ValueError(f"no session database {path}")
    store = Store(path)
    try:
        options = OptionsStore(store)
        latest: dict[str, tuple[dict[str, Any], list[OptionsTrialRecord]]] = {}
        excluded: list[ExcludedSession] = []
        sets: set[tuple[str, ...]] = set()
        for s in store.sessions():  # oldest first: a later session supersedes
            names = options.names(str(s["session"]))
            if names is None:
                continue  # the paper's two options: `nod analyze study`
            modes = _schedule_modes(s.get("config"))
            if modes and modes != PAPER_MODES:
                raise ValueError(
                    f"session {s['session']} ran another schedule than trials 1-3 dissensus, "
                    "4-8 consensus: the study statistics here need that structure"
                )
            trials = options.trials(str(s["session"]))
            if s["status"] != "complete" or {t.trial for t in trials} < set(TRIALS):
                excluded.append(ExcludedSession(
                    str(s["session"]), str(s["participant"]), str(s["status"]), len(trials),
                    len(trials), len(TRIALS), f"{s['status']} with {len(trials)} of 8 trials"))
                continue
            sets.add(names)
            latest[str(s["participant"])] = (s, trials)
    finally:
        store.close()
    if not latest:
        raise ValueError(f"no complete session of three or more options in {path}: run "
                         "`nod run --sim --options 3` first")
    if len(sets) > 1:
        raise ValueError(f"the sessions ran different option sets {sorted(sets)}: one at a time")
    (names,) = sets
    parts = [
        ParticipantOutcomes(pid, str(s["session"]), str(s["status"]),
                            {t.trial: None if t.interrupted else t.outcome for t in trials},
                            frozenset(t.trial for t in trials if t.interrupted),
                            rig=str(s["rig"]))
        for pid, (s, trials) in latest.items()
    ]
    doc = analyze_study(parts, excluded=excluded)
    doc["options"] = list(names)
    doc["option_shares"] = option_shares(names, [trials for _, trials in latest.values()])
    return doc


def summary(doc: dict[str, Any]) -> str:
    """A few lines for the terminal: per trial, the outcomes and the option shares."""
    names = doc["options"]
    lines = [f"{doc['participants']} participant(s), options {', '.join(names)}",
             f"{'trial':>5}  {'C':>3} {'CH':>3} {'D':>3} {'DH':>3}  human presses / agreement"]
    for trial in map(str, doc["trials"]):
        f, sh = doc["frequencies"][trial], doc["option_shares"][trial]
        presses = " ".join(f"{n}:{sh['human'][n]}" for n in names)
        agree = (f"both on O {sh['both_on_o']}/{sh['n']}" if "both_on_o" in sh
                 else f"robot elsewhere {sh['robot_not_human']}/{sh['n']}")
        lines.append(f"{trial:>5}  {f['C']:>3} {f['CH']:>3} {f['D']:>3} {f['DH']:>3}  "
                     f"{presses}  {agree}")
    test = doc["stuart_maxwell"]["control_vs_experiment"]
    lines.append("control vs experiment (Stuart-Maxwell): " + (
        f"chi2 = {test['statistic']:.3f}, df = {test['df']}, p = {test['p']:.4g}"
        if "p" in test else f"undefined ({test.get('error', '')})"))
    return "\n".join(lines)
