"""The study analysis of paper Secs 7-8 (Fig 8) over every session of a database (SPEC §7).

Units and rules:

- **Inclusion** (services.analysis.sessions, stated in every report): by default only complete
  sessions (status complete, every scheduled trial stored); `min_trials = N` lets in any
  session with at least N scored trials. Every session left out is listed in `excluded` with
  its reason ("aborted after 4 of 8 trials"). A participant who withdrew is not read at all,
  sessions nor answers (`services.store.withdrawals`), unless `include_withdrawn`; `withdrawn`
  names them and carries the one line the command prints.
- A *participant* is the `participant` column of the sessions table. When a participant has
  several sessions that pass the rule, the most recent one is analysed and the others are
  excluded as superseded (e.g. a full re-run).
- Outcomes are C, CH, D, DH per trial. A stored trial without an outcome (the human never
  pressed: a timeout), a trial interrupted by a safe stop, and a trial never stored (an
  incomplete session let in by `min_trials`) are *excluded trial-wise*: each is listed in
  `excluded_trials`, counted as `none` in the per-trial frequencies (so each trial's
  frequencies sum to the number of participants), and left out of every categorical test. A
  phase category is taken over the phase's remaining trials; a participant with no outcome in
  a phase, or without both trials of an adjacent pair, drops out of that table.
- Phases: control = trials 1-3, experiment = trials 4-8. A participant's category in a phase is
  its most frequent outcome there; a tie goes to the outcome seen in the later trial.
- Stuart-Maxwell (services.analysis.stuart_maxwell) on the control × experiment table and on
  each adjacent pair 4→5 … 7→8; rows are the earlier classification. An undefined test (e.g.
  every pair concordant) is reported with its reason instead of numbers. The defined tests are
  one family for the correction for multiple comparisons (services.analysis.multiplicity; Holm
  by default): each carries its raw `p` and its `p_adjusted`.
- Questionnaire: one-sample t-tests (scipy.stats.ttest_1samp, two-sided) of Q1, Q2, Q4, Q5
  against the scale midpoint 5.5 with Cohen's d = (mean − 5.5)/sd (sd with ddof 1); χ² goodness
  of fit (scipy.stats.chisquare) of Q3's Yes/No/Maybe counts against uniform, with Cohen's
  w = √(χ²/n) and Cramér's V = √(χ²/(n(k − 1))), k = 3. The answers of a participant whose
  every session is excluded are left out too (listed in `questionnaire_excluded`).
- Small samples (services.analysis.exact): every test says whether its approximation holds
  (`approximation_ok`: ≥ 10 discordant pairs per df, expected counts ≥ 5, n ≥ 5) and, where it
  does not, gives an exact p (`p_exact`: conditional Stuart-Maxwell, multinomial, sign-flip)
  and a `caveat` the report prints beside the p. The correction still adjusts the χ² p's.
- **One parameter set**: the analysed sessions must have run the same parameters (the params
  hash of each conductor run's provenance, `services.core.provenance`). Sessions that differ
  are refused in one line naming them, unless `mixed_params` pools them anyway (the line is
  then a note); sessions stored without provenance are listed as `unknown`, never refused.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from services.analysis.exact import goodness_of_fit_small, stuart_maxwell_small, t_test_small
from services.analysis.multiplicity import Correction, adjust
from services.analysis.sessions import (
    OUTCOMES,
    TRIALS,
    ExcludedSession,
    InclusionRule,
    ParticipantOutcomes,
    describe_labels,
    select_sessions,
)
from services.analysis.stuart_maxwell import stuart_maxwell
from services.core.provenance import mixed_params
from services.model.geometry import COLOURS
from services.model.phases import CONTROL_TRIALS, EXPERIMENT_TRIALS, phase_category
from services.store import QuestionnaireRecord
from services.store.provenance import read_provenance
from services.store.study_stores import open_stores
from services.store.withdrawals import withdrawn_filter

ADJACENT_PAIRS: tuple[tuple[int, int], ...] = ((4, 5), (5, 6), (6, 7), (7, 8))
LIKERT_MIDPOINT = 5.5
LIKERT_KEYS: tuple[str, ...] = ("q1", "q2", "q4", "q5")
Q3_CHOICES: tuple[str, ...] = ("Yes", "No", "Maybe")


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
    doc.update(stuart_maxwell_small(table, result.kept, result.df))  # honest about few pairs
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
    doc.update(t_test_small(x.tolist(), midpoint))
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
    doc.update(goodness_of_fit_small(observed))
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


def correct(tests: dict[str, dict[str, Any]], method: Correction) -> list[str]:
    """Add `p_adjusted` to every defined test of the family, in place; return the family's names.

    The family is the tests that have a p-value (an undefined test is not a comparison made).
    """
    family = [name for name, t in tests.items() if "p" in t]
    for name, q in zip(family, adjust([tests[n]["p"] for n in family], method), strict=True):
        tests[name]["p_adjusted"] = q
    return family


def analyze_study(
    parts: Sequence[ParticipantOutcomes],
    questionnaires: Sequence[QuestionnaireRecord] = (),
    notes: Sequence[str] = (),
    excluded: Sequence[ExcludedSession] = (),
    rule: InclusionRule | None = None,
    correction: Correction = "holm",
) -> dict[str, Any]:
    """Every number of the Sec 7-8 study analysis as one JSON-ready document.

    `parts` are the sessions the inclusion `rule` let in, `excluded` those it left out (both as
    `select_sessions` gives them); `correction` adjusts the Stuart-Maxwell family's p-values.
    """
    rule = rule or InclusionRule()
    if not parts and not excluded:
        raise ValueError("no session with stored trials: run `nod run` first")
    if not parts:
        first = excluded[0]
        raise ValueError(
            f"no session passes the inclusion rule: all {len(excluded)} excluded (e.g. "
            f"{first.session} of {first.participant}: {first.reason}); --min-trials N lets "
            "in sessions with at least N scored trials"
        )
    sets = {p.options for p in parts}
    if len(sets) > 1:  # one table per study (`one_option_set` picks one)
        raise ValueError(f"the sessions ran {len(sets)} option sets: analyse one at a time")
    (names,) = sets
    trial_excluded = [
        {
            "participant": p.participant,
            "trial": trial,
            "reason": "interrupted" if trial in p.interrupted
            else "timeout" if trial in p.outcomes else "missing",
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
    family = correct(tests, correction)
    rules = sorted({p.control_labels for p in parts})
    labels = rules[0] if len(rules) == 1 else "mixed"
    included = {p.participant for p in parts}
    left_out = {e.participant for e in excluded} - included
    answers = [q for q in questionnaires if q.participant not in left_out]
    answered = {q.participant for q in answers}
    return {
        "categories": list(OUTCOMES),
        "trials": list(TRIALS),
        "control_trials": list(CONTROL_TRIALS),
        "experiment_trials": list(EXPERIMENT_TRIALS),
        "inclusion": rule.as_dict(),
        "control_labels": {
            "rule": labels,
            "description": describe_labels(labels),
            "sessions": {r: sum(p.control_labels == r for p in parts) for r in rules},
        },
        "participants": len(parts),
        "sessions": [
            {"participant": p.participant, "session": p.session, "status": p.status,
             "control_labels": p.control_labels, "rig": p.rig}
            for p in parts
        ],
        "rigs": {r: sum(p.rig == r for p in parts) for r in sorted({p.rig for p in parts})},
        "excluded": [e.as_dict() for e in excluded],
        "notes": list(notes),
        "grid": {p.participant: [p.outcome(t) for t in TRIALS] for p in parts},
        "excluded_trials": trial_excluded,
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
        "correction": correction,
        "correction_family": family,
        "stuart_maxwell": tests,
        "questionnaire": questionnaire_stats(answers),
        "questionnaire_excluded": sorted({q.participant for q in questionnaires} & left_out),
        "questionnaire_without_session": sorted(answered - included),
        "sessions_without_questionnaire": sorted(included - answered),
        "options": list(names),
        "option_shares": option_shares(names, parts),
    }


def one_option_set(
    parts: Sequence[ParticipantOutcomes], options: Sequence[str] | None = None
) -> tuple[list[ParticipantOutcomes], list[ExcludedSession]]:
    """The sessions of the option set analysed, and the sessions of any other set, left out.

    The statistics compare outcomes (C, CH, D, DH), which mean the same for any number of
    options, but a study is one table: sessions run with other buzzers are another study.
    `options` picks the set; by default the only one there, else the paper's (red, blue) if
    any session ran it. Several sets and no choice is a ValueError naming them (one line).
    """
    sets = sorted({p.options for p in parts})
    if options is not None:
        chosen = tuple(options)
    elif len(sets) <= 1:
        chosen = sets[0] if sets else COLOURS
    elif COLOURS in sets:
        chosen = COLOURS
    else:
        listed = "; ".join(",".join(s) for s in sets)
        raise ValueError(f"the sessions ran {len(sets)} option sets ({listed}): --options "
                         "NAMES picks the one to analyse")
    kept = [p for p in parts if p.options == chosen]
    other = [
        ExcludedSession(
            p.session, p.participant, p.status, len(p.outcomes),
            len(p.outcomes) - len(p.interrupted), len(TRIALS),
            f"ran options {', '.join(p.options)}: --options {','.join(p.options)} analyses them",
        )
        for p in parts
        if p.options != chosen
    ]
    return kept, other


def option_shares(
    names: Sequence[str], parts: Sequence[ParticipantOutcomes]
) -> dict[str, dict[str, Any]]:
    """Per trial: how many humans and robots pressed each option, and the agreements.

    `human` / `robot`: presses per option name (`human.none`: no press, a timeout or an
    interrupted trial); `both_on_o` in a consensus trial: both pressed O (the consensus claim);
    `robot_not_human` in a control trial: the robot pressed another box than the human.
    """
    out: dict[str, dict[str, Any]] = {}
    for trial in TRIALS:
        recs = [p.choices[trial] for p in parts if trial in p.choices]
        row: dict[str, Any] = {
            "n": len(recs),
            "human": {n: sum(h == n for _, h, _ in recs) for n in names},
            "robot": {n: sum(r == n for _, _, r in recs) for n in names},
        }
        row["human"]["none"] = sum(h is None for _, h, _ in recs)
        if trial in CONTROL_TRIALS:
            row["robot_not_human"] = sum(
                r is not None and h is not None and r != h for _, h, r in recs
            )
        else:
            row["both_on_o"] = sum(o is not None and h == o == r for o, h, r in recs)
        out[str(trial)] = row
    return out


def load_study(
    paths: str | Sequence[str], rule: InclusionRule | None = None,
    correction: Correction = "holm", include_withdrawn: bool = False,
    options: Sequence[str] | None = None, pool_mixed_params: bool = False,
) -> dict[str, Any]:
    """Open the study's stores (one per rig, or one), select their sessions, analyse them as one.

    A participant id in two stores or on two rigs is a ValueError (`open_stores`), not a merge.
    Withdrawn participants are left out (sessions and answers) unless `include_withdrawn`.
    The sessions of one option set are analysed (`one_option_set`; `options` picks it).
    Sessions that ran different parameters are a ValueError naming them, unless
    `pool_mixed_params` (module doc).
    """
    names = [paths] if isinstance(paths, str) else list(paths)
    with open_stores(names) as stores:
        keep = withdrawn_filter([store for _, store in stores], include_withdrawn)
        chosen = [select_sessions(store, rule, keep) for _, store in stores]
        answers = [q for _, store in stores for q in store.questionnaires()
                   if keep.keeps(q.participant)]
        parts = sorted((p for c in chosen for p in c.participants), key=lambda p: p.participant)
        parts, other = one_option_set(parts, options)
        runs = [(r.session, r.provenance.params_hash) for _, store in stores
                for r in read_provenance(store, [p.session for p in parts])]
    params = params_sets(runs, [p.session for p in parts], pool_mixed_params)
    doc = analyze_study(
        parts, sorted(answers, key=lambda q: q.participant),
        [n for c in chosen for n in c.notes], [e for c in chosen for e in c.excluded] + other,
        chosen[0].rule, correction,
    )
    withdrawn = {"left_out": keep.left_out, "included": sorted(keep.withdrawn) if
                 include_withdrawn else [], "note": keep.note()}
    return {**doc, "stores": names, "withdrawn": withdrawn, "params": params}


def params_sets(
    runs: Sequence[tuple[str, str]], sessions: Sequence[str], pool: bool
) -> dict[str, Any]:
    """The analysed sessions by params hash, those of unknown provenance, and a note.

    The note is the one line saying they differ (None when they do not); ValueError with that
    line if they differ and not `pool`.
    """
    line = mixed_params(runs)
    if line is not None and not pool:
        raise ValueError(f"{line}: not pooled (--mixed-params pools them anyway)")
    by_hash: dict[str, list[str]] = {}
    for session, digest in runs:
        by_hash.setdefault(digest, []).append(session)
    known = {s for s, _ in runs}
    return {"by_hash": {h: sorted(set(s)) for h, s in sorted(by_hash.items())},
            "unknown": sorted(set(sessions) - known),
            "note": None if line is None else f"{line}: pooled (--mixed-params)"}
