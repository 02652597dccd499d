"""The study analysis of paper Secs 7-8 (Fig 8) over every session of a database (SPEC §7).

Units and rules:

- A *participant* is the `participant` column of the sessions table. When a participant has
  several sessions, the most recent one that stored any trial is analysed and the others are
  listed in `notes` (e.g. a re-run after an aborted session).
- Outcomes are C, CH, D, DH per trial. A stored trial without an outcome (the human never
  pressed: a timeout) and a trial that was never stored (an aborted session) are *excluded*:
  each is listed in `excluded_trials`, counted as `none` in the per-trial frequencies (so each
  trial's frequencies sum to the number of participants), and left out of every categorical
  test. A phase category is taken over the phase's remaining trials; a participant with no
  outcome in a phase, or without both trials of an adjacent pair, drops out of that table.
- Phases: control = trials 1-3, experiment = trials 4-8. A participant's category in a phase is
  its most frequent outcome there; a tie goes to the outcome seen in the later trial.
- Stuart-Maxwell (services.analysis.stuart_maxwell) on the control × experiment table and on
  each adjacent pair 4→5 … 7→8; rows are the earlier classification. An undefined test (e.g.
  every pair concordant) is reported with its reason instead of numbers.
- Questionnaire: one-sample t-tests (scipy.stats.ttest_1samp, two-sided) of Q1, Q2, Q4, Q5
  against the scale midpoint 5.5 with Cohen's d = (mean − 5.5)/sd (sd with ddof 1); χ² goodness
  of fit (scipy.stats.chisquare) of Q3's Yes/No/Maybe counts against uniform, with Cohen's
  w = √(χ²/n) and Cramér's V = √(χ²/(n(k − 1))), k = 3.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from services.analysis.stuart_maxwell import stuart_maxwell
from services.store import QuestionnaireRecord, Store

OUTCOMES: tuple[str, ...] = ("C", "CH", "D", "DH")
TRIALS: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 7, 8)
CONTROL_TRIALS: tuple[int, ...] = (1, 2, 3)
EXPERIMENT_TRIALS: tuple[int, ...] = (4, 5, 6, 7, 8)
ADJACENT_PAIRS: tuple[tuple[int, int], ...] = ((4, 5), (5, 6), (6, 7), (7, 8))
LIKERT_MIDPOINT = 5.5
LIKERT_KEYS: tuple[str, ...] = ("q1", "q2", "q4", "q5")
Q3_CHOICES: tuple[str, ...] = ("Yes", "No", "Maybe")


@dataclass(frozen=True, slots=True)
class ParticipantOutcomes:
    """One participant's analysed session: trial number → outcome (None: timeout)."""

    participant: str
    session: str
    status: str
    outcomes: Mapping[int, str | None]  # stored trials only; a missing trial has no key

    def outcome(self, trial: int) -> str | None:
        """The trial's outcome, or None for a timeout or a trial never stored."""
        return self.outcomes.get(trial)


def load_participants(store: Store) -> tuple[list[ParticipantOutcomes], list[str]]:
    """Each participant's latest session with trials, ordered by participant id; plus notes."""
    latest: dict[str, ParticipantOutcomes] = {}
    notes: list[str] = []
    for s in store.sessions():  # oldest first, so later sessions overwrite earlier ones
        trials = store.trials(s["session"])
        if not trials:
            notes.append(f"session {s['session']} ({s['participant']}) has no trials: skipped")
            continue
        bad = sorted(
            {t.outcome for _, t in trials if t.outcome is not None and t.outcome not in OUTCOMES}
        )
        if bad:
            raise ValueError(f"session {s['session']}: unknown outcome(s) {bad}")
        for _, t in trials:
            if t.interrupted:  # broken by a safe stop or e-stop: never scored, never counted
                notes.append(
                    f"session {s['session']} ({s['participant']}) trial {t.trial} was "
                    "interrupted by a safe stop: excluded"
                )
        part = ParticipantOutcomes(
            participant=str(s["participant"]),
            session=str(s["session"]),
            status=str(s["status"]),
            outcomes={t.trial: None if t.interrupted else t.outcome for _, t in trials},
        )
        if part.participant in latest:
            notes.append(
                f"participant {part.participant}: session {latest[part.participant].session} "
                f"superseded by the later session {part.session}"
            )
        latest[part.participant] = part
    return [latest[p] for p in sorted(latest)], notes


def phase_category(outcomes: Sequence[str | None]) -> str | None:
    """The most frequent outcome of a phase's trials (in trial order); ties go to the later trial.

    None entries (timeouts, missing trials) are ignored; None if nothing is left.
    """
    counts = Counter(o for o in outcomes if o is not None)
    if not counts:
        return None
    top = max(counts.values())
    last_seen = {o: i for i, o in enumerate(outcomes) if o is not None}
    return max((o for o, n in counts.items() if n == top), key=lambda o: last_seen[o])


def paired_table(pairs: Iterable[tuple[str | None, str | None]]) -> np.ndarray:
    """The 4×4 table of paired outcomes (rows: first, columns: second; order C, CH, D, DH).

    Pairs with a None on either side are left out.
    """
    table = np.zeros((len(OUTCOMES), len(OUTCOMES)), dtype=int)
    for a, b in pairs:
        if a is not None and b is not None:
            table[OUTCOMES.index(a), OUTCOMES.index(b)] += 1
    return table


def stuart_maxwell_doc(table: np.ndarray | Sequence[Sequence[int]]) -> dict[str, Any]:
    """Stuart-Maxwell of a paired table as JSON: statistic, df, p, categories kept, or an error."""
    table = np.asarray(table, dtype=int)
    doc: dict[str, Any] = {"n": int(table.sum()), "table": table.tolist()}
    try:
        result = stuart_maxwell(table)
    except ValueError as exc:
        doc["error"] = str(exc)
        return doc
    doc.update(
        statistic=result.statistic,
        df=result.df,
        p=result.p,
        categories_kept=[OUTCOMES[i] for i in result.kept],
    )
    return doc


def likert_test(values: Sequence[int], midpoint: float = LIKERT_MIDPOINT) -> dict[str, Any]:
    """One-sample two-sided t-test of ratings against the midpoint, with Cohen's d."""
    x = np.asarray(values, dtype=float)
    doc: dict[str, Any] = {"n": int(x.size), "midpoint": midpoint}
    if x.size < 2:
        doc["error"] = f"need at least 2 answers for a t-test, have {x.size}"
        return doc
    mean, sd = float(x.mean()), float(x.std(ddof=1))
    doc.update(mean=mean, sd=sd)
    if sd == 0.0:
        doc["error"] = f"every answer is {x[0]:g}: zero spread, the t-test is undefined"
        return doc
    from scipy.stats import ttest_1samp  # lazy: scipy.stats is slow to import

    res = ttest_1samp(x, midpoint)
    doc.update(
        t=float(res.statistic),
        df=int(x.size - 1),
        p=float(res.pvalue),
        cohens_d=(mean - midpoint) / sd,
    )
    return doc


def q3_test(answers: Sequence[str]) -> dict[str, Any]:
    """χ² goodness of fit of Yes/No/Maybe counts against uniform, with Cohen's w and Cramér's V."""
    counts = Counter(answers)
    unknown = sorted(set(counts) - set(Q3_CHOICES))
    if unknown:
        raise ValueError(f"Q3 answers must be {', '.join(Q3_CHOICES)}; got {unknown}")
    observed = [counts[c] for c in Q3_CHOICES]
    n = sum(observed)
    doc: dict[str, Any] = {"n": n, "counts": dict(zip(Q3_CHOICES, observed, strict=True))}
    if n == 0:
        doc["error"] = "no Q3 answers"
        return doc
    from scipy.stats import chisquare

    res = chisquare(observed)
    chi2 = float(res.statistic)
    k = len(Q3_CHOICES)
    doc.update(
        expected=n / k,
        chi2=chi2,
        df=k - 1,
        p=float(res.pvalue),
        cohens_w=math.sqrt(chi2 / n),
        cramers_v=math.sqrt(chi2 / (n * (k - 1))),
    )
    return doc


def questionnaire_stats(records: Sequence[QuestionnaireRecord]) -> dict[str, Any]:
    """The Sec 8 statistics of every stored questionnaire."""
    doc: dict[str, Any] = {"n": len(records)}
    for key in LIKERT_KEYS:
        doc[key] = likert_test([getattr(r, key) for r in records])
    doc["q3"] = q3_test([r.q3 for r in records])
    return doc


def frequencies(parts: Sequence[ParticipantOutcomes]) -> dict[str, dict[str, int]]:
    """Fig 8a: per trial, how many participants had each outcome; `none` counts exclusions."""
    out: dict[str, dict[str, int]] = {}
    for trial in TRIALS:
        counts = Counter(p.outcome(trial) for p in parts)
        row = {o: counts[o] for o in OUTCOMES}
        row["none"] = counts[None]
        row["n"] = len(parts)
        out[str(trial)] = row
    return out


def flows(table: np.ndarray) -> list[dict[str, Any]]:
    """Fig 8b: the non-zero control → experiment flows of a contingency table."""
    return [
        {"from": OUTCOMES[i], "to": OUTCOMES[j], "count": int(table[i, j])}
        for i in range(len(OUTCOMES))
        for j in range(len(OUTCOMES))
        if table[i, j] > 0
    ]


def analyze_study(
    parts: Sequence[ParticipantOutcomes],
    questionnaires: Sequence[QuestionnaireRecord] = (),
    notes: Sequence[str] = (),
) -> dict[str, Any]:
    """Every number of the Sec 7-8 study analysis as one JSON-ready document."""
    if not parts:
        raise ValueError("no session with stored trials: run `nod run` first")
    excluded = [
        {
            "participant": p.participant,
            "trial": trial,
            "reason": "timeout" if trial in p.outcomes else "missing",
        }
        for p in parts
        for trial in TRIALS
        if p.outcome(trial) is None
    ]
    phases = {
        p.participant: {
            "control": phase_category([p.outcome(t) for t in CONTROL_TRIALS]),
            "experiment": phase_category([p.outcome(t) for t in EXPERIMENT_TRIALS]),
        }
        for p in parts
    }
    table = paired_table((c["control"], c["experiment"]) for c in phases.values())
    tests = {"control_vs_experiment": stuart_maxwell_doc(table)}
    for a, b in ADJACENT_PAIRS:
        pair = paired_table((p.outcome(a), p.outcome(b)) for p in parts)
        tests[f"trial_{a}_vs_{b}"] = stuart_maxwell_doc(pair)
    answered = {q.participant for q in questionnaires}
    return {
        "categories": list(OUTCOMES),
        "trials": list(TRIALS),
        "control_trials": list(CONTROL_TRIALS),
        "experiment_trials": list(EXPERIMENT_TRIALS),
        "participants": len(parts),
        "sessions": [
            {"participant": p.participant, "session": p.session, "status": p.status} for p in parts
        ],
        "notes": list(notes),
        "grid": {p.participant: [p.outcome(t) for t in TRIALS] for p in parts},
        "excluded_trials": excluded,
        "frequencies": frequencies(parts),
        "phase_categories": phases,
        "contingency": {
            "rows": "control",
            "columns": "experiment",
            "table": table.tolist(),
            "row_totals": table.sum(axis=1).tolist(),
            "column_totals": table.sum(axis=0).tolist(),
            "excluded_participants": sorted(
                p for p, c in phases.items() if c["control"] is None or c["experiment"] is None
            ),
        },
        "flows": flows(table),
        "stuart_maxwell": tests,
        "questionnaire": questionnaire_stats(questionnaires),
        "questionnaire_without_session": sorted(answered - {p.participant for p in parts}),
        "sessions_without_questionnaire": sorted({p.participant for p in parts} - answered),
    }


def load_study(path: str) -> dict[str, Any]:
    """Open a session database, analyse every participant, close it."""
    store = Store(path)
    try:
        parts, notes = load_participants(store)
        answers = store.questionnaires()
    finally:
        store.close()
    return analyze_study(parts, answers, notes)
