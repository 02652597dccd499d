"""The subcommands of `nod analyze`, one function each.

Each reads its parsed flags, runs the analysis library and prints or writes the result;
`services.analysis.cli` is the parser and the entry point.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from services.model.dynamics import PairParams


class UsageError(Exception):
    """A bad input found after parsing; reported as one line with exit code 2."""


def pair_params(path: str | None) -> PairParams:
    """The dynamics (eqs 1-2) of a params file: its [decision.pair]; SPEC's if None.

    The same file every other command takes with `--params` (deploy/params.example.toml).
    """
    from services.core.config import load_params

    return load_params(path).decision.pair


def thresholds(args: argparse.Namespace) -> int:
    """`nod analyze thresholds`: u*, u_d* and the origin's eigenvalues (Sec 4.3).

    With more than two options (or β, δ ≠ 0) the N_o-option model's report instead.
    """
    from services.analysis.thresholds_report import report

    doc, table = report(pair_params(args.params), args.options, args.beta, args.delta)
    print(json.dumps(doc, indent=2) if args.json else table)
    return 0


def sweep(args: argparse.Namespace) -> int:
    """`nod analyze sweep`: the consensus map over (b_r, b_h) (Fig 3a)."""
    from rich.console import Console
    from rich.progress import Progress

    from services.analysis.sweep import bias_grid, save_npz, sweep, sweep_rk4

    p = pair_params(args.params)
    out = Path(args.out)
    if not out.parent.is_dir():
        raise UsageError(f"--out: directory {str(out.parent)!r} does not exist")
    b = bias_grid(args.grid, args.range)
    console = Console(stderr=True)  # a bar only on a terminal: logs and pipes stay clean
    start = time.perf_counter()
    solver = sweep if args.method == "newton" else sweep_rk4
    with Progress(console=console, disable=args.no_progress or not console.is_terminal) as bar:
        task = bar.add_task(f"sweep {args.grid}×{args.grid}", total=1.0)
        result = solver(b, b, p, progress=lambda done: bar.update(task, completed=done))
    elapsed = time.perf_counter() - start
    try:
        save_npz(result, out, p)
        if args.png:
            from services.analysis.plots import plot_sweep

            plot_sweep(result, args.png, p.robot.u)
    except OSError as exc:
        raise UsageError(f"cannot write output: {exc}") from None
    print(
        f"wrote {out}: {args.grid}×{args.grid} grid over [-{args.range:g}, {args.range:g}]², "
        f"consensus {result.consensus.mean():.2%}, converged {result.converged.mean():.2%}, "
        f"method {result.method}, compute {elapsed:.3f} s"
    )
    return 0


def paper_claims(args: argparse.Namespace) -> int:
    """`nod analyze paper-claims`: the paper's numeric claims, checked."""
    from services.analysis.paper_claims import format_report, report

    doc = report(pair_params(args.params), args.grid)
    print(json.dumps(doc, indent=2) if args.json else format_report(doc))
    return 0


def nullclines(args: argparse.Namespace) -> int:
    """`nod analyze nullclines`: both panels of Fig 3b."""
    from services.analysis.figures import FORMATS
    from services.analysis.plots import plot_nullcline_pair

    suffix = Path(args.out).suffix.lower().lstrip(".")
    if suffix not in FORMATS:
        raise UsageError(f"--out must end in .{', .'.join(FORMATS)}, got {args.out!r}")
    p = pair_params(args.params)
    try:
        panels = plot_nullcline_pair(p, args.offset, args.out)
    except OSError as exc:
        raise UsageError(f"cannot write {args.out}: {exc}") from None
    for letter, eqs in zip("ab", panels, strict=True):
        kinds = ", ".join(f"{e.stability} ({e.z_r:+.3f}, {e.z_h:+.3f})" for e in eqs)
        print(f"({letter}) {len(eqs)} equilibria: {kinds}")
    print(f"wrote {args.out}")
    return 0


def equilibria(args: argparse.Namespace) -> int:
    """`nod analyze equilibria`: every equilibrium at fixed biases, with its stability."""
    from services.analysis.equilibria import find_equilibria

    p = pair_params(args.params)
    eqs = find_equilibria(args.br, args.bh, p)
    if args.png:
        from services.analysis.plots import plot_nullclines

        try:
            plot_nullclines(args.br, args.bh, p, eqs, args.png)
        except OSError as exc:
            raise UsageError(f"cannot write {args.png}: {exc}") from None
    if args.json:
        doc = {"b_r": args.br, "b_h": args.bh, "equilibria": [e.as_dict() for e in eqs]}
        print(json.dumps(doc, indent=2))
    else:
        print(f"b_r = {args.br:g}, b_h = {args.bh:g}: {len(eqs)} equilibria")
        for e in eqs:
            eig = ", ".join(f"{v.real:.4g}{v.imag:+.4g}j" for v in e.eigenvalues)
            tag = "consensus" if e.consensus else "dissensus"
            print(f"  z_r = {e.z_r:+.8f}  z_h = {e.z_h:+.8f}  {e.stability:<14} {tag:<9}  λ: {eig}")
    return 0


def square_claim(args: argparse.Namespace) -> int:
    """`nod analyze square-claim`: the square-region claim of Sec 4.4.1."""
    from services.analysis.square_claim import check_square_claim, format_report
    from services.analysis.sweep import bias_grid, sweep

    p = pair_params(args.params)
    b = bias_grid(args.grid, args.range)
    report = check_square_claim(sweep(b, b, p), p.robot.u)
    print(json.dumps(report, indent=2) if args.json else format_report(report))
    return 0


def stuart_maxwell(args: argparse.Namespace) -> int:
    """`nod analyze stuart-maxwell`: the test on a 4x4 outcome table (Secs 7-8)."""
    from services.analysis.stuart_maxwell import stuart_maxwell

    try:
        table: Any = json.loads(args.table)
    except json.JSONDecodeError as exc:
        raise UsageError(f"--table is not valid JSON ({exc.msg} at char {exc.pos})") from None
    result = stuart_maxwell(table)
    if args.json:
        print(json.dumps(result.as_dict()))
    else:
        kept = ", ".join(str(i) for i in result.kept)
        print(
            f"X² = {result.statistic:.6g}, df = {result.df}, p = {result.p:.4g} "
            f"(categories kept: {kept})"
        )
    return 0


def study(args: argparse.Namespace) -> int:
    """`nod analyze study`: the study's statistics and figures from a session store."""
    from services.analysis.study import InclusionRule, load_study
    from services.analysis.study_figures import write_figures
    from services.analysis.study_report import finite_json, markdown, summary

    rule = InclusionRule(args.min_trials)
    options = args.options.split(",") if args.options else None
    doc = finite_json(
        load_study(args.db, rule, args.correction, args.include_withdrawn, options,
                   args.mixed_params)
    )
    for note in (doc["withdrawn"]["note"], doc["params"]["note"]):
        if note:  # one line, on stderr: stdout stays the summary or the JSON
            print(f"nod analyze study: {note}", file=sys.stderr)
    if args.out:
        out = Path(args.out)
        try:
            figures = write_figures(doc, out, args.format)
            (out / "study.json").write_text(json.dumps(doc, indent=2) + "\n")
            (out / "report.md").write_text(markdown(doc, figures))
        except OSError as exc:
            raise UsageError(f"cannot write to --out {args.out!r}: {exc}") from None
    if args.json:
        print(json.dumps(doc, indent=2, allow_nan=False))
    else:
        print(summary(doc))
        if args.out:
            kinds = "/".join(args.format)
            print(f"wrote {Path(args.out) / 'report.md'}, study.json and {len(figures)} figures "
                  f"({kinds})")
    return 0


def bstar(args: argparse.Namespace) -> int:
    """`nod analyze bstar`: the b* margin derived from a press-time requirement."""
    from services.analysis.bstar import derive_margin
    from services.core.config import load_params

    cfg = load_params(args.params)
    margin, runs = derive_margin(args.press_s, cfg, seeds=max(1, args.seeds))
    u_r = cfg.decision.pair.robot.u
    worst = max(r.agree_s for r in runs)
    doc = {
        "press_s": args.press_s,
        "margin": margin,
        "b_star": u_r + margin,
        "u_r": u_r,
        "latest_agreement_s": worst,
        "runs": len(runs),
    }
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        print(
            f"b* = u_r + {margin:.1f} = {u_r + margin:.2f}: the robot is on O's side by "
            f"{worst:.2f} s after go in all {len(runs)} runs, before a press at {args.press_s} s"
        )
    return 0


def power(args: argparse.Namespace) -> int:
    """`nod analyze power`: the study size for the paper's effects (simulated cohorts).

    K independent populations (`--populations`, `--population` people each) are simulated on
    the engine; the power is pooled over them, with an interval that holds their spread, at the
    chosen correction and uncorrected (the paper's), beside what the paper's own X² implies.
    """
    import time

    from services.analysis.multiplicity import NAMES, Correction
    from services.analysis.power import (
        PAPER_N,
        TESTS,
        paper_implied,
        plot,
        populations,
        power,
    )
    from services.cohort.person import load_cohort_params
    from services.compute.engine import EngineError, engine_from_args

    sizes = _sizes(args.participants)
    if not (1 <= args.runs <= 100_000 and 10 <= args.population <= 1_000_000 and args.alpha < 1):
        raise UsageError("--runs 1-100000, --population 10-1000000, --alpha in (0, 1)")
    if max(sizes) > args.population:
        raise UsageError(
            f"--participants {max(sizes)} > --population {args.population}: a study is drawn "
            "from distinct people of one population; give a larger --population"
        )
    corrections: list[Correction] = [args.correction]
    if args.correction != "none":
        corrections.append("none")
    cfg = load_cohort_params(args.params)
    t0 = time.monotonic()
    try:
        with engine_from_args(args) as engine:
            pops = populations(engine, cfg, args.populations, args.population, args.seed)
    except EngineError as exc:
        raise UsageError(str(exc)) from None
    simulated = time.monotonic() - t0
    results = power(pops, sizes, args.runs, args.alpha, args.seed, corrections)
    doc = {
        "method": "K independent simulated populations (disjoint seeds), studies of N distinct "
        "people drawn from each; power pooled over populations, 95% interval "
        "mean ± t(K-1)·s/√K over the populations' shares, at least the Wilson interval of "
        "all draws",
        "populations": args.populations,
        "population": args.population,
        "seeds": [args.seed, args.seed + args.populations * args.population - 1],
        "alpha": args.alpha,
        "corrections": corrections,
        "params": args.params,
        "seconds": round(time.monotonic() - t0, 1),
        "simulation_seconds": round(simulated, 1),
        "results": results,
        "paper_implied": paper_implied(sizes),
    }
    if args.out:
        out = Path(args.out)
        try:
            out.mkdir(parents=True, exist_ok=True)
            (out / "power.json").write_text(json.dumps(doc, indent=2) + "\n")
            plot(doc, str(out / "power.png"))
            plot(doc, str(out / "power.pdf"))
        except OSError as exc:
            raise UsageError(f"cannot write to --out {args.out!r}: {exc}") from None
    if args.json:
        print(json.dumps(doc, indent=2))
        return 0
    print(f"power at α = {args.alpha}, pooled over {args.populations} independent populations of "
          f"{args.population} simulated people ({args.runs} studies of distinct people per size "
          f"and population; {doc['seconds']} s); 95% intervals include the spread between "
          "populations:")
    names = [t.replace("trial_", "").replace("_vs_", "→") for t in TESTS]
    print("  N    " + f"{'':<12}" + "".join(f"{t:>23}" for t in names))
    for r in results:
        for c in corrections:
            cells = [f"{r['power'][c][t]:.2f} [{r['ci95'][c][t][0]:.2f}-{r['ci95'][c][t][1]:.2f}]"
                     for t in TESTS]
            print(f"  {r['participants']:<5}{NAMES[c]:<12}" + "".join(f"{x:>23}" for x in cells))
    implied = doc["paper_implied"]["tests"]
    print(f"the paper's own statistics imply (noncentral χ², λ = X² − df scaled by N/{PAPER_N}; "
          f"α = {args.alpha} uncorrected; in brackets λ = X², the optimistic plug-in):")
    for t, name in zip(TESTS, names, strict=True):
        first = implied[t][str(PAPER_N)]
        at = "  ".join(f"N={n} {v['power']:.2f} [{v['power_plug_in']:.2f}]"
                       for n, v in implied[t].items())
        print(f"  {name:<23} X² {first['statistic']:g}, df {first['df']}: {at}")
    return 0


def trial(args: argparse.Namespace) -> int:
    """`nod analyze trial`: one stored trial's streams as a figure (Figs 6-7)."""
    from services.analysis.sessions import resolve_session
    from services.analysis.trial_plot import figure, trial_title
    from services.core.config import load_params
    from services.store import Store

    formats = args.format
    db = Path(args.db)
    if not db.is_file():
        raise UsageError(f"--db: no such database {args.db!r}")
    store = Store(db)
    try:
        session, participant = resolve_session(store, args.session, args.participant)
        trials = store.trials(session)
        match = [t for _, t in trials if t.trial == args.trial]
        if not match:
            have = ", ".join(str(t.trial) for _, t in trials) or "none"
            raise UsageError(
                f"participant {participant} (session {session}) has no trial {args.trial}; "
                f"stored: {have}"
            )
        samples = store.samples(session, args.trial)
        names = store.option_names(session)
    finally:
        store.close()
    rec = match[0]
    cfg = load_params(args.params)
    layout = cfg.layout if len(names) == 2 else cfg.table(len(names))
    try:
        paths = figure(samples, rec, layout, trial_title(participant, rec), Path(args.out),
                       formats, names)
    except OSError as exc:
        raise UsageError(f"cannot write to --out {args.out!r}: {exc}") from None
    print(f"participant {participant}, session {session}, trial {rec.trial}: wrote "
          + ", ".join(str(p) for p in paths))
    return 0


def _sizes(text: str) -> list[int]:
    """Study sizes from `--participants 20,40,60` (2 to 10000 each)."""
    try:
        sizes = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise UsageError(f"--participants must be sizes like 20,40,60, got {text!r}") from None
    if not sizes or min(sizes) < 2 or max(sizes) > 10_000:
        raise UsageError("--participants: sizes between 2 and 10000")
    return sizes


def policies(args: argparse.Namespace) -> int:
    """`nod analyze policies`: the paper's robot against another policy's, on two cohorts."""
    from services.analysis.policies import compare, load_condition, markdown

    sizes = _sizes(args.participants)
    doc = compare(load_condition(args.paper_db), load_condition(args.adaptive_db), args.seed,
                  args.bootstrap, sizes, args.runs, args.alpha)
    print(json.dumps(doc, indent=2) if args.json else markdown(doc), end="" if not args.json
          else "\n")
    return 0


COMMANDS = {
    "policies": policies,
    "trial": trial,
    "power": power,
    "bstar": bstar,
    "thresholds": thresholds,
    "sweep": sweep,
    "equilibria": equilibria,
    "nullclines": nullclines,
    "paper-claims": paper_claims,
    "square-claim": square_claim,
    "stuart-maxwell": stuart_maxwell,
    "study": study,
}
