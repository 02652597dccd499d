"""`nod analyze policies`: two robots' cohorts compared, per consensus trial and per kind.

Each store is one condition (`nod cohort --policy …`): its complete sessions, each a
participant. Per participant and consensus trial: C on O (the person pressed O, without a
switch, and the robot with them: outcome C) and C + CH on O (agreement on O); over trials 4–8
each participant's share of them; the time from "go" to the trial's end in trials that ended in
agreement on O (the store keeps go and end; the press itself only with samples). Each share
with a 95 % percentile-bootstrap interval over participants, and the difference of the two
robots with one (each condition resampled on its own: a between-subjects comparison), overall
and per kind of person where the store knows it (`policy_sessions.kind`, the simulated
person's; a real participant has none). When both stores hold the same sessions (the same
seeds: the same simulated people), the difference also gets a paired interval (the people
resampled together). The power of a real between-subjects study of the two robots with N
participants per robot: studies of N drawn from each cohort with replacement, each tested
with Welch's t on the participants' C share over trials 4–8, two-sided at α; the share
significant is the power (with its binomial 95 % interval).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from services.model.phases import CONTROL_TRIALS
from services.model.policy import KINDS
from services.store import Store
from services.store.cohorts import refuse_unfinished
from services.store.policies import read_policies

CONSENSUS = (4, 5, 6, 7, 8)  # the paper's consensus trials
LATE = CONSENSUS  # the target's span: trials 4–8


@dataclass(frozen=True)
class Participant:
    """One participant of a condition: per consensus trial C on O, C + CH on O, time."""

    session: str
    kind: str | None
    c: dict[int, bool]
    agree: dict[int, bool]
    seconds: dict[int, float]  # go → end, trials that ended in agreement on O

    def share(self, which: str, trials: Sequence[int] = LATE) -> float:
        """The participant's share of C (or C + CH) on O over `trials` that were played."""
        got = self.c if which == "c" else self.agree
        played = [got[t] for t in trials if t in got]
        return sum(played) / len(played) if played else math.nan


@dataclass(frozen=True)
class Condition:
    """One store's participants and the policy they met."""

    path: str
    policy: str
    sha256: str
    people: tuple[Participant, ...]


def load_condition(path: str | Path) -> Condition:
    """The complete sessions of one store (ValueError if it holds an unfinished cohort)."""
    store = Store(path)
    try:
        refuse_unfinished(store, str(path))
        policies = read_policies(store)
        people = []
        for s in store.sessions():
            if s["status"] != "complete":
                continue
            name = s["session"]
            c, agree, seconds = {}, {}, {}
            for _, t in store.trials(name):
                if t.trial in CONTROL_TRIALS or t.mode != "consensus" or t.interrupted:
                    continue
                on_o = t.option is not None and t.human == t.option and t.robot == t.option
                c[t.trial] = on_o and t.outcome == "C"
                agree[t.trial] = on_o and t.outcome in ("C", "CH")
                if agree[t.trial] and t.t_go_ns is not None and t.t_end_ns is not None:
                    seconds[t.trial] = (t.t_end_ns - t.t_go_ns) / 1e9
            pol = policies.get(name)
            people.append(Participant(name, pol.kind if pol else None, c, agree, seconds))
    finally:
        store.close()
    if not people:
        raise ValueError(f"{path} holds no complete session")
    names = {p.policy for p in policies.values()} or {"paper (no policy stored)"}
    hashes = {p.sha256 for p in policies.values()}
    if len(names) > 1 or len(hashes) > 1:
        raise ValueError(f"{path} holds sessions of several policies ({sorted(names)}): one "
                         "store is one condition")
    return Condition(str(path), names.pop(), hashes.pop() if hashes else "", tuple(people))


def _boot(values: np.ndarray, rng: np.random.Generator, reps: int) -> np.ndarray:
    """Means of `reps` resamples (with replacement) of `values`."""
    idx = rng.integers(0, len(values), size=(reps, len(values)))
    return values[idx].mean(axis=1)


def estimate(a: np.ndarray, b: np.ndarray, rng: np.random.Generator, reps: int,
             paired: bool = False) -> dict[str, Any]:
    """Means of a and b, b − a, each with a 95 % percentile-bootstrap interval.

    `paired`: a[i] and b[i] are the same simulated person (the same seed in both cohorts):
    also the interval of the difference with the pairs resampled together (`diff_paired_ci`),
    which a simulation can give (common random numbers) and a between-subjects study cannot.
    """
    both = ~np.isnan(a) & ~np.isnan(b) if paired and len(a) == len(b) else None
    pa, pb = (a[both], b[both]) if both is not None else (a[:0], b[:0])
    a, b = a[~np.isnan(a)], b[~np.isnan(b)]
    if len(a) == 0 or len(b) == 0:
        return {"n": [len(a), len(b)]}
    ba, bb = _boot(a, rng, reps), _boot(b, rng, reps)

    def ci(x: np.ndarray) -> list[float]:
        return [float(np.percentile(x, 2.5)), float(np.percentile(x, 97.5))]

    out = {"n": [len(a), len(b)], "paper": float(a.mean()), "paper_ci": ci(ba),
           "adaptive": float(b.mean()), "adaptive_ci": ci(bb),
           "diff": float(b.mean() - a.mean()), "diff_ci": ci(bb - ba)}
    if len(pa):
        out["diff_paired_ci"] = ci(_boot(pb - pa, rng, reps))
    return out


def power(a: np.ndarray, b: np.ndarray, n: int, rng: np.random.Generator, runs: int,
          alpha: float) -> dict[str, Any]:
    """Power of a between-subjects study with n per robot (module doc)."""
    hits = 0
    for _ in range(runs):
        x, y = rng.choice(a, n), rng.choice(b, n)
        if x.std() == 0 and y.std() == 0:
            hits += int(x.mean() != y.mean())
            continue
        hits += int(stats.ttest_ind(y, x, equal_var=False).pvalue < alpha)
    p = hits / runs
    half = 1.96 * math.sqrt(p * (1 - p) / runs)
    return {"n_per_robot": n, "power": p, "ci95": [max(0.0, p - half), min(1.0, p + half)]}


def compare(paper: Condition, adaptive: Condition, seed: int = 1, reps: int = 2000,
            sizes: Sequence[int] = (20, 40, 60), runs: int = 1000, alpha: float = 0.05
            ) -> dict[str, Any]:
    """Every number of the comparison (module doc), as plain data."""
    rng = np.random.default_rng(seed)
    paired = [p.session for p in paper.people] == [p.session for p in adaptive.people]

    def col(cond: Condition, which: str, trials: Sequence[int] = LATE,
            kind: str | None = None) -> np.ndarray:
        return np.array([p.share(which, trials) for p in cond.people
                         if kind is None or p.kind == kind], dtype=float)

    def secs(cond: Condition) -> np.ndarray:
        return np.array([np.mean(list(p.seconds.values())) for p in cond.people if p.seconds])

    out: dict[str, Any] = {
        "paper": {"store": paper.path, "policy": paper.policy, "sha256": paper.sha256,
                  "participants": len(paper.people)},
        "adaptive": {"store": adaptive.path, "policy": adaptive.policy,
                     "sha256": adaptive.sha256, "participants": len(adaptive.people)},
        "paired": paired,
        "per_trial": {str(t): {w: estimate(col(paper, w, (t,)), col(adaptive, w, (t,)), rng,
                                           reps, paired) for w in ("c", "c_ch")}
                      for t in CONSENSUS},
        "trials_4_8": {w: estimate(col(paper, w), col(adaptive, w), rng, reps, paired)
                       for w in ("c", "c_ch")},
        "seconds_to_agreement": estimate(secs(paper), secs(adaptive), rng, reps),
        "per_kind": {k: {w: estimate(col(paper, w, kind=k), col(adaptive, w, kind=k), rng,
                                     reps, paired and _same_kinds(paper, adaptive))
                         for w in ("c", "c_ch")} for k in KINDS},
    }
    out["per_kind"] = {k: v for k, v in out["per_kind"].items() if "diff" in v["c"]}
    a, b = col(paper, "c"), col(adaptive, "c")
    a, b = a[~np.isnan(a)], b[~np.isnan(b)]
    out["power"] = [power(a, b, n, rng, runs, alpha) for n in sizes]
    out["settings"] = {"seed": seed, "bootstrap": reps, "runs": runs, "alpha": alpha}
    return out


def _same_kinds(a: Condition, b: Condition) -> bool:
    """Whether the paired people are of the same kinds (so per kind they pair up too)."""
    return [p.kind for p in a.people] == [p.kind for p in b.people]


def _pct(x: float) -> str:
    return f"{100 * x:5.1f}"


def _row(label: str, e: dict[str, Any]) -> str:
    if "diff" not in e:
        return f"| {label} | – | – | – | – | n = {e['n']} |"
    lo, hi = e["diff_ci"]
    diff = f"{100 * e['diff']:+.1f} [{100 * lo:+.1f}, {100 * hi:+.1f}]"
    pl, ph = e.get("diff_paired_ci", (math.nan, math.nan))
    paired = f"[{100 * pl:+.1f}, {100 * ph:+.1f}]" if "diff_paired_ci" in e else "–"
    return (f"| {label} | {_pct(e['paper'])} | {_pct(e['adaptive'])} | {diff} | {paired} | "
            f"{e['n'][0]}, {e['n'][1]} |")


def markdown(doc: dict[str, Any]) -> str:
    """The comparison as Markdown tables (percentages; differences adaptive − paper)."""
    head = ("| | paper % | adaptive % | difference, points [95 % CI] | paired 95 % CI | "
            "N paper, adaptive |\n|---|---|---|---|---|---|")
    lines = [f"paper: {doc['paper']['store']} ({doc['paper']['policy']}, "
             f"{doc['paper']['participants']} people); adaptive: {doc['adaptive']['store']} "
             f"({doc['adaptive']['policy']} {doc['adaptive']['sha256'][:12]}, "
             f"{doc['adaptive']['participants']} people)", "", "C on O (no switch, both on O)",
             "", head]
    lines += [_row(f"trial {t}", v["c"]) for t, v in doc["per_trial"].items()]
    lines.append(_row("**trials 4–8**", doc["trials_4_8"]["c"]))
    lines += ["", "C + CH on O (agreement on O)", "", head]
    lines += [_row(f"trial {t}", v["c_ch"]) for t, v in doc["per_trial"].items()]
    lines.append(_row("**trials 4–8**", doc["trials_4_8"]["c_ch"]))
    lines += ["", "Per kind of person, trials 4–8", "", head]
    for k, v in doc["per_kind"].items():
        lines += [_row(f"{k}: C", v["c"]), _row(f"{k}: C + CH", v["c_ch"])]
    s = doc["seconds_to_agreement"]
    if "diff" in s:
        lines += ["", f"Seconds from go to the end of a trial agreed on O (mean per participant): "
                  f"paper {s['paper']:.2f}, adaptive {s['adaptive']:.2f}, difference "
                  f"{s['diff']:+.2f} [{s['diff_ci'][0]:+.2f}, {s['diff_ci'][1]:+.2f}]"]
    lines += ["", "Power of a between-subjects study (Welch t on each participant's C share, "
              f"trials 4–8, α = {doc['settings']['alpha']}, {doc['settings']['runs']} drawn "
              "studies)", "", "| N per robot | power [95 % CI] |", "|---|---|"]
    lines += [f"| {p['n_per_robot']} | {p['power']:.2f} [{p['ci95'][0]:.2f}, {p['ci95'][1]:.2f}] |"
              for p in doc["power"]]
    return "\n".join(lines) + "\n"
