"""`nod fit`'s and `nod fit recovery`'s results as JSON documents and as text tables.

`nod fit --json`: {"participants": [{"participant", "session", "trials", "parameters": {NAME:
{"estimate", "low", "high"}}, "prior_check": {"p", "outside"}, "predictive": {...}}],
"not_identifiable": {NAME: {...}}, "prior_check": {how it is made}, ...}:
only parameters that passed the recovery check are under "parameters" — the others are named,
with their check, and never given an estimate. A 0/1 parameter (a kind) is {"estimate": its
most likely value, "probability", "set": [0] | [1] | [0, 1], "low", "high": the set's least
and largest}: every estimate lies inside its own interval or set. `nod fit recovery --json`:
{"parameters": [{"name", "correlation", "correlation_ci95", "bias", "coverage",
"coverage_ci95", "identifiable", "edge", "n", ...}], "model_recovery": {...}, "prior_check":
{"flagged", "n", "rate", "rate_ci95", ...}, "population", "intervals": {how they were found}}:
r's interval a percentile bootstrap over the people, the coverage's and the flag rate's Wilson's.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from services.fit.data import Person
from services.fit.estimator import LEVEL, Estimates
from services.fit.prior_check import ALPHA
from services.fit.prior_check import METHOD as PRIOR_METHOD
from services.fit.simulate import Simulated
from services.model.recovery import Recovery, wilson
from services.model.summaries import summary_names

OUTCOME_KEYS = ("C", "CH", "D", "DH", "none")
PRIOR_CHECK = {
    "alpha": ALPHA,
    "method": PRIOR_METHOD,
}
UNITS = {"speed": "image widths/s", "reaction_s": "s", "perception_delay_s": "s"}
MEANING = {
    "preference_mean": "strength of the person's own preference (|b_h| of eq 2)",
    "gaze_gain": "use of the gaze: the eyes' pull per radian of yaw, per unit of trust",
    "trust0": "trust in the eyes at the first gaze trial",
    "gaze_use": "use of the gaze at the first gaze trial: gaze_gain × trust0",
    "speed": "hand speed (peak, image widths per second)",
    "reaction_s": "reaction time from go to the first movement (s)",
    "perception_delay_s": "how late the person sees the arm's heading (s)",
    "late_switcher": "probability that the person plays the strategic late switch (control)",
    "contrarian": "probability that the person distrusts the eyes (consensus trials)",
    "firm_contrarian": "probability that the person holds the box the eyes do not look at "
    "against the robot (a firm contrarian: their own preference's strength)",
    "persistent_contrarian": "probability that the person distrusts the eyes in every consensus "
    "trial (a persistent contrarian: never comes round)",
}


def shares(outcomes: Sequence[str | None]) -> dict[str, float]:
    """The share of each outcome (a timeout: "none") over a person's trials."""
    counts = Counter(o or "none" for o in outcomes)
    n = max(1, len(outcomes))
    return {k: counts[k] / n for k in OUTCOME_KEYS}


_PRESS = [i for i, n in enumerate(summary_names()) if n.startswith("press_") and n[6:].isdigit()]


def press_times(summaries: np.ndarray) -> list[float]:
    """A session's press times (s from go) as its summaries read them: one reading for all."""
    return [float(summaries[i]) for i in _PRESS if math.isfinite(summaries[i])]


def _press_times(sims: Sequence[Simulated]) -> list[float]:
    return sorted(p for s in sims for p in press_times(s.summaries))


def _r(x: float) -> float:
    return round(float(x), 4)


def parameter_cell(estimate: float, low: float, high: float, probability: float
                   ) -> dict[str, Any]:
    """One parameter of one person in the JSON: a 0/1 one (probability not NaN) with its set."""
    cell: dict[str, Any] = {"estimate": _r(estimate), "low": _r(low), "high": _r(high)}
    if math.isfinite(probability):
        cell["probability"] = _r(probability)
        cell["set"] = [v for v in (0, 1) if low <= v <= high]
    return cell


def prior_cell(p: float) -> dict[str, Any]:
    """One person's out-of-prior check in the JSON: its p-value, and whether it is flagged."""
    return {"p": _r(p), "outside": bool(p < ALPHA)}


def fit_document(people: Sequence[Person], fit: Estimates, checks: Sequence[Recovery],
                 sims: Sequence[Sequence[Simulated]], observed_press: Sequence[list[float]],
                 meta: dict[str, Any], prior_p: Sequence[float] | None = None
                 ) -> dict[str, Any]:
    """The JSON document of `nod fit`; `prior_p`: each person's out-of-prior p-value."""
    ok = {c.name for c in checks if c.identifiable}
    rows = []
    for i, person in enumerate(people):
        params = {
            name: parameter_cell(fit.estimate[i, p], fit.low[i, p], fit.high[i, p],
                                 fit.probability[i, p])
            for p, name in enumerate(fit.names) if name in ok
        }
        row: dict[str, Any] = {
            "participant": person.participant, "session": person.session,
            "trials": sum(1 for t in person.paths if not t.interrupted),
            "parameters": params,
        }
        if prior_p is not None:
            row["prior_check"] = prior_cell(prior_p[i])
        if sims[i]:
            simulated = [o for s in sims[i] for o in s.outcomes]
            row["predictive"] = {
                "observed": shares(person.outcomes), "simulated": shares(simulated),
                "observed_press_s": [_r(p) for p in observed_press[i]],
                "simulated_press_s": [_r(p) for p in _press_times(sims[i])],
                "sessions": len(sims[i]),
            }
        rows.append(row)
    return {
        "participants": rows,
        "identifiable": sorted(ok, key=list(fit.names).index),
        "not_identifiable": {c.name: c.as_dict() for c in checks if not c.identifiable},
        "check": [c.as_dict() for c in checks],
        "level": LEVEL,
        "prior_check": PRIOR_CHECK,
        "meaning": {n: MEANING.get(n, n) for n in fit.names},
        **meta,
    }


def table_cell(v: dict[str, Any]) -> str:
    """`estimate [low, high]`; a 0/1 parameter `value (p probability) {set}`."""
    if "probability" in v:
        members = ", ".join(str(m) for m in v["set"])
        return f"{v['estimate']:>8.3g} (p {v['probability']:.2f}) {{{members}}}"
    return f"{v['estimate']:>8.3g} [{v['low']:.3g}, {v['high']:.3g}]"


def prior_text(cell: dict[str, Any] | None) -> str:
    """`ok (p 0.43)` or `OUTSIDE (p 0.01)`; blank when the person was not checked."""
    if cell is None:
        return ""
    return f"{'OUTSIDE' if cell['outside'] else 'ok'} (p {cell['p']:.2f})"


def fit_table(doc: dict[str, Any]) -> str:
    """The per-participant table: estimate [low, high] of each identifiable parameter.

    A 0/1 parameter shows its most likely value, its probability and its set, so the value
    read in the estimate column is a value the person can have. Beside the estimates, the
    out-of-prior check: a person flagged OUTSIDE is one the prior does not reproduce, whose
    intervals are not calibrated for them.
    """
    names = doc["identifiable"]
    lines = [f"{'participant':<12} {'trials':>6} {'prior':>16}  "
             + "  ".join(f"{n:>22}" for n in names)]
    for row in doc["participants"]:
        cells = [table_cell(row["parameters"][n]).rjust(22) for n in names]
        lines.append(f"{row['participant']:<12} {row['trials']:>6} "
                     f"{prior_text(row.get('prior_check')):>16}  " + "  ".join(cells))
    lines.append(f"(estimate [{int(LEVEL * 100)} % interval]; a kind: most likely value "
                 f"(p its probability) {{{int(LEVEL * 100)} % set}}; "
                 f"{', '.join(names) or 'none'} recovered on held-out simulated people)")
    flagged = [r["participant"] for r in doc["participants"]
               if r.get("prior_check", {}).get("outside")]
    lines.append(f"(prior: the out-of-prior check, p below {ALPHA:g} OUTSIDE — the prior does not "
                 f"reproduce the person's summaries and their intervals are not calibrated for "
                 f"them; flagged: {', '.join(flagged) or 'none'})")
    for name, c in doc["not_identifiable"].items():
        lines.append(
            f"not identifiable from these trials, no estimate given: {name} "
            f"({MEANING.get(name, name)}; recovery r = {_fmt(c['correlation'])}, "
            f"coverage {_fmt(c['coverage'])})"
        )
    return "\n".join(lines)


def _fmt(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.2f}"


def _ci(pair: Sequence[float | None]) -> str:
    return f"[{_fmt(pair[0])}, {_fmt(pair[1])}]"


def flag_rate(flagged: int, n: int) -> dict[str, Any]:
    """How many planted people the out-of-prior check flagged, with a 95 % Wilson interval."""
    return {"flagged": flagged, "n": n, "rate": _r(flagged / n) if n else None,
            "rate_ci95": [_r(v) for v in wilson(flagged, n)], **PRIOR_CHECK}


def recovery_table(checks: Sequence[Recovery], model: dict[str, Any] | None,
                   intervals: Sequence[dict[str, Any]] | None = None,
                   prior_check: dict[str, Any] | None = None,
                   versus: dict[str, Any] | None = None) -> str:
    """The recovery study as text: one line per parameter, then the model-recovery check.

    With `intervals` (`recovery_intervals`, one per check): r and coverage each with its 95 %
    interval, and a verdict that another draw of people could turn marked "(at the edge)".
    """
    w = max([len("parameter"), *(len(c.name) for c in checks)])  # a long name keeps the columns
    cis = intervals is not None
    head = f"{'parameter':<{w}} {'r':>6} "
    head += f"{'r 95 % CI':>14} " if cis else ""
    head += f"{'bias':>8} {'coverage':>9} "
    head += f"{'coverage 95 % CI':>16} " if cis else ""
    lines = [head + " identifiable"]
    for j, c in enumerate(checks):
        d = c.as_dict()
        u = intervals[j] if intervals is not None else {}
        line = f"{c.name:<{w}} {_fmt(d['correlation']):>6} "  # type: ignore[arg-type]
        line += f"{_ci(u['correlation_ci95']):>14} " if cis else ""
        line += f"{_fmt(d['bias']):>8} {_fmt(d['coverage']):>9} "  # type: ignore[arg-type]
        line += f"{_ci(u['coverage_ci95']):>16} " if cis else ""
        verdict = "yes" if c.identifiable else "NO"
        lines.append(line + f" {verdict}" + (" (at the edge)" if u.get("edge") else ""))
    lines.append(f"(standard: r ≥ 0.7 and {int(LEVEL * 100)} % coverage within 0.80-0.98; "
                 f"n = {checks[0].n if checks else 0})")
    if cis:
        lines.append("(95 % intervals: r's a percentile bootstrap over the people, from the "
                     "run's seed; coverage's Wilson's. At the edge: either reaches across its "
                     "threshold, so another draw of people could turn the verdict)")
    logged = [c.name for c in checks if c.scale == "log"]
    if logged:
        lines.append(f"(r of {', '.join(logged)}: of the logs, a trait spread log-normally "
                     "across people)")
    if prior_check:
        lo, hi = prior_check["rate_ci95"]
        lines.append(f"out-of-prior check: {prior_check['flagged']} of {prior_check['n']} "
                     f"planted people flagged outside the prior ({prior_check['rate']:.2f}, "
                     f"95 % CI {lo:.2f}-{hi:.2f}; at most {ALPHA:g} expected of the prior's "
                     "own people)")
    if model:
        lines.append(f"model recovery (gaze term or not): accuracy {model['accuracy']:.2f} on "
                     f"{model['sessions']} held-out sessions")
    if versus:
        lines.append(f"model recovery (the prior or {versus['versus']}): accuracy "
                     f"{versus['accuracy']:.2f} on {versus['sessions']} held-out sessions (the "
                     f"prior's told right {versus['first']:.2f}, the other's "
                     f"{versus['second']:.2f})")
    return "\n".join(lines)


def by_length_table(checks: Mapping[int, Sequence[Recovery]]) -> str:
    """The recovery study at each session length: per parameter, r and coverage after k trials.

    `--json` has each check whole, with the intervals' mean width.
    """
    lengths = sorted(checks)
    names = [c.name for c in checks[lengths[0]]]
    w = max([len("parameter"), *(len(n) for n in names)])
    head = f"{'parameter':<{w}} " + " ".join(f"{f'k={k} r/cov':>12}" for k in lengths)
    lines = [head]
    for j, name in enumerate(names):
        cells = [f"{_fmt(checks[k][j].correlation)}/{_fmt(checks[k][j].coverage)}"
                 for k in lengths]
        lines.append(f"{name:<{w}} " + " ".join(f"{c:>12}" for c in cells))
    n = checks[lengths[0]][0].n if names else 0
    lines.append(f"(r of the estimates with the truth and the {int(LEVEL * 100)} % intervals' "
                 f"coverage, on the same n = {n} people after their first k trials; a kind's r "
                 "is of its probability)")
    return "\n".join(lines)
