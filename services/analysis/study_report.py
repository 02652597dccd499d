"""The Markdown report and the terminal summary of the study analysis (Secs 7-8).

Everything here formats the JSON document of services.analysis.study.analyze_study; no number
is computed twice. The figures it links are services.analysis.study_figures'.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from services.analysis.multiplicity import NAMES, Correction
from services.analysis.study import LIKERT_KEYS, OUTCOMES
from services.analysis.study_figures import TITLES
from services.model.geometry import COLOURS


def _num(x: float | None, digits: int = 4) -> str:
    if x is None:
        return "–"
    if x != 0 and (abs(x) < 1e-3 or abs(x) >= 1e5):
        return f"{x:.{digits - 1}e}"
    return f"{x:.{digits}g}"


def _sm_short(t: Mapping[str, Any], correction: Correction) -> str:
    """One test in one line: X², df, raw p, adjusted p (unless uncorrected), n."""
    if "error" in t:
        return f"Stuart-Maxwell undefined (n = {t['n']})"
    adjusted = "" if correction == "none" else (
        f", {NAMES[correction]} p = {_num(t['p_adjusted'], 3)}"
    )
    return (
        f"X² = {t['statistic']:.3f}, df = {t['df']}, p = {_num(t['p'], 3)}{adjusted} "
        f"(n = {t['n']}){_caveat(t)}"
    )


def _caveat(t: Mapping[str, Any]) -> str:
    """A test's small-sample caveat, as said beside its p ("" when its approximation holds)."""
    return f" — {t['caveat']}" if t.get("caveat") else ""


def _correction_line(doc: Mapping[str, Any]) -> str:
    """The correction for multiple comparisons, stated as the report states it."""
    family = len(doc["correction_family"])
    if doc["correction"] == "none":
        return f"No correction for multiple comparisons over the {family} Stuart-Maxwell tests."
    return (
        f"Correction for multiple comparisons: {NAMES[doc['correction']]} over the family of "
        f"{family} defined Stuart-Maxwell tests (family-wise error rate; compare the adjusted "
        "p with α)."
    )


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(r) + " |" for r in rows]


def markdown(doc: Mapping[str, Any], figures: Mapping[str, Path] | None = None) -> str:
    """The Markdown report: data, figures and every statistic of the JSON document."""
    n = doc["participants"]
    md = ["# Study report (paper Secs 7-8, Fig 8)", ""]
    md.append(
        f"{n} participants; control = trials {doc['control_trials']}, experiment = trials "
        f"{doc['experiment_trials']}."
    )
    md += ["", f"Inclusion: {doc['inclusion']['description']}."]
    if sources(doc):
        md += ["", f"Data: {sources(doc)}."]
    md += ["", f"Labels: {doc['control_labels']['description']}."]
    gone = doc["excluded"]
    md += ["", f"Excluded sessions ({len(gone)}):" if gone else "Excluded sessions: none."]
    md += [f"- {e['participant']} (session {e['session']}): {e['reason']}" for e in gone]
    if doc["questionnaire_excluded"]:
        md.append(
            "- their questionnaire answers are left out too: "
            + ", ".join(doc["questionnaire_excluded"])
        )
    for note in doc["notes"]:
        md.append(f"- note: {note}")
    ex = doc["excluded_trials"]
    md += ["", f"Excluded from the categorical tests: {len(ex)} trial(s) without an outcome."]
    md += [f"- {e['participant']} trial {e['trial']}: {e['reason']}" for e in ex]
    if doc["contingency"]["excluded_participants"]:
        md.append(
            "- no phase category (left out of the contingency table): "
            + ", ".join(doc["contingency"]["excluded_participants"])
        )
    if figures:
        md += ["", "## Figures", ""]
        md += [f"![{f'Fig {k}' if k[0].isdigit() else 'Figure'}: {TITLES[k]}]({p.name})\n"
           for k, p in figures.items()]
    md += ["", "## Frequencies per trial (Fig 8a)", ""]
    md += _table(
        ["trial", *OUTCOMES, "none", "n"],
        [
            [t, *(f"{r[o]} ({100 * r[o] / n:.2f}%)" for o in OUTCOMES), str(r["none"]), str(r["n"])]
            for t, r in doc["frequencies"].items()
        ],
    )
    cont = doc["contingency"]
    md += ["", "## Contingency table, control (rows) × experiment (columns) (Fig 8d)", ""]
    md += _table(
        ["control \\ experiment", *OUTCOMES, "total"],
        [
            [o, *(str(v) for v in row), str(tot)]
            for o, row, tot in zip(OUTCOMES, cont["table"], cont["row_totals"], strict=True)
        ]
        + [["total", *(str(v) for v in cont["column_totals"]), str(sum(cont["row_totals"]))]],
    )
    md += [
        "",
        "Flows (Fig 8b): "
        + (", ".join(f"{f['from']}→{f['to']} {f['count']}" for f in doc["flows"]) or "none"),
    ]
    md += ["", "## Stuart-Maxwell tests of marginal homogeneity", "", _correction_line(doc), ""]
    rows = []
    for name, t in doc["stuart_maxwell"].items():
        label = name.replace("_", " ").replace("vs", "→").replace("trial ", "trials ")
        if "error" in t:
            rows.append([label, str(t["n"]), "–", "–", "–", "–", "–", t["error"]])
        else:
            rows.append(
                [
                    label,
                    str(t["n"]),
                    f"{t['statistic']:.4f}",
                    str(t["df"]),
                    _num(t["p"]),
                    _num(t["p_adjusted"]),
                    " ".join(t["categories_kept"]),
                    t.get("caveat", ""),
                ]
            )
    adjusted = f"p ({NAMES[doc['correction']]})"
    md += _table(
        ["comparison", "n", "X²", "df", "p (raw)", adjusted, "categories kept", "note"], rows
    )
    q = doc["questionnaire"]
    md += ["", f"## Questionnaire (Sec 8), {q['n']} answer sets", ""]
    rows = []
    for key in LIKERT_KEYS:
        t = q[key]
        rows.append(
            [
                key.upper(),
                str(t["n"]),
                _num(t.get("mean")),
                _num(t.get("sd")),
                _num(t.get("t")),
                str(t.get("df", "–")),
                _num(t.get("p")),
                _num(t.get("cohens_d")),
                t.get("error", t.get("caveat", "")),
            ]
        )
    md += _table(
        ["question", "n", "mean", "sd", "t (vs 5.5)", "df", "p", "Cohen's d", "note"], rows
    )
    q3 = q["q3"]
    counts = ", ".join(f"{k} {v}" for k, v in q3["counts"].items())
    md += [
        "",
        f"Q3 ({counts}): "
        + (
            q3["error"]
            if "error" in q3
            else f"χ² = {q3['chi2']:.4f}, df = {q3['df']}, p = {_num(q3['p'])}, Cohen's w = "
            f"{q3['cohens_w']:.4f}, Cramér's V = {q3['cramers_v']:.4f}{_caveat(q3)}"
        ),
    ]
    if doc["sessions_without_questionnaire"]:
        md.append("\nNo questionnaire yet: " + ", ".join(doc["sessions_without_questionnaire"]))
    if doc["questionnaire_without_session"]:
        md.append(
            "\nQuestionnaire without a session: " + ", ".join(doc["questionnaire_without_session"])
        )
    md += [
        "",
        "## Method",
        "",
        f"Inclusion: {doc['inclusion']['description']}. "
        f"Labels: {doc['control_labels']['description']}. "
        "Phase category = most frequent outcome of the phase's trials, ties to the later "
        "trial; timeouts, interrupted and missing trials are excluded from every categorical "
        "test. Stuart-Maxwell drops categories empty in both margins. "
        + _correction_line(doc)
        + " The questionnaire tests are not corrected. t-tests are one-sample, "
        "two-sided, against 5.5; Cohen's d = (mean − 5.5)/sd; Q3 χ² against uniform with "
        "Cohen's w = √(χ²/n) and Cramér's V = √(χ²/(2n)).",
        "",
    ]
    return "\n".join(md)


def sources(doc: Mapping[str, Any]) -> str:
    """Where a study of several stores or rigs came from ("" for one store of one rig)."""
    stores, rigs = doc.get("stores", []), doc.get("rigs", {})
    if len(stores) < 2 and len(rigs) < 2:
        return ""
    per_rig = ", ".join(f"{n} on {rig or 'an unnamed rig'}" for rig, n in rigs.items())
    return f"{len(stores)} store(s) ({', '.join(stores)}), participants {per_rig}"


def _presses(row: Mapping[str, Any], names: Sequence[str]) -> str:
    """One trial's option shares, short: the human's presses and the agreement counted."""
    presses = " ".join(f"{n}:{row['human'][n]}" for n in names)
    agree = (f"both on O {row['both_on_o']}/{row['n']}" if "both_on_o" in row
             else f"robot elsewhere {row['robot_not_human']}/{row['n']}")
    return f"  | {presses}  {agree}"


def summary(doc: Mapping[str, Any]) -> str:
    """A few lines for the terminal."""
    lines = [
        f"{doc['participants']} participants ({doc['inclusion']['label']}); "
        f"{len(doc['excluded'])} session(s) excluded, "
        f"{len(doc['excluded_trials'])} trial(s) excluded (timeout/interrupted/missing)"
    ]
    if sources(doc):
        lines.append(f"  from {sources(doc)}")
    lines += [f"  excluded {e['participant']} ({e['session']}): {e['reason']}"
              for e in doc["excluded"]]
    names = doc.get("options", list(COLOURS))
    more = names != list(COLOURS)  # another table than the paper's: its presses per trial
    if more:
        lines.append(f"  options {', '.join(names)}: per trial the human's presses, and both "
                     "on O (consensus trials) or the robot elsewhere (control trials)")
    for t, r in doc["frequencies"].items():
        lines.append(
            f"  trial {t}: "
            + "  ".join(f"{o} {r[o]:>2}" for o in OUTCOMES)
            + (f"  none {r['none']}" if r["none"] else "")
            + (_presses(doc["option_shares"][t], names) if more else "")
        )
    family = len(doc["correction_family"])
    how = (
        "uncorrected p" if doc["correction"] == "none"
        else f"p adjusted by {NAMES[doc['correction']]}"
    )
    lines.append(f"  Stuart-Maxwell, {family} tests, {how}:")
    for name, t in doc["stuart_maxwell"].items():
        lines.append(f"  {name}: {_sm_short(t, doc['correction'])}")
    q = doc["questionnaire"]
    if q["n"] == 0:
        lines.append("  questionnaire: no answers stored (enter them with `nod questionnaire`)")
        return "\n".join(lines)
    for key in LIKERT_KEYS:
        t = q[key]
        lines.append(
            f"  {key}: "
            + (
                t["error"]
                if "error" in t
                else f"mean {t['mean']:.2f}, t = {t['t']:.3f}, p = {_num(t['p'], 3)}, "
                f"d = {t['cohens_d']:.3f}{_caveat(t)}"
            )
        )
    q3 = q["q3"]
    lines.append(
        "  q3: "
        + (
            q3["error"]
            if "error" in q3
            else f"χ² = {q3['chi2']:.3f}, p = {_num(q3['p'], 3)}, w = {q3['cohens_w']:.3f}"
            f"{_caveat(q3)}"
        )
    )
    return "\n".join(lines)


def finite_json(value: Any) -> Any:
    """Replace non-finite floats by None so the document is strict JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite_json(v) for v in value]
    return value
