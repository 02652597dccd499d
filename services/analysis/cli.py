"""`nod analyze …`: thin command-line shell over the analysis library.

Subcommands: thresholds (Sec 4.3), sweep (Fig 3a), equilibria (Fig 3b), nullclines (Fig 3b, both
panels), paper-claims and square-claim (Sec 4.4.1), stuart-maxwell (Secs 7-8), study (Secs 7-8,
Fig 8), trial (Figs 6-7), power (study size), bstar (the b* margin). Every bad input ends with
one line on stderr, `nod analyze <sub>: error: <what and how to fix>`, and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from services.core.cli import Parser, fail, finite_float, positive_float
from services.model.dynamics import PairParams

PROG = "nod analyze"


class UsageError(Exception):
    """A bad input found after parsing; reported as one line with exit code 2."""


def _formats(text: str) -> tuple[str, ...]:
    from services.analysis.figures import parse_formats

    try:
        return parse_formats(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _grid_size(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 2:
        raise argparse.ArgumentTypeError(f"must be an integer >= 2, got {text!r}")
    return value


def load_params(path: str | None) -> PairParams:
    """PairParams from a TOML file's [dynamics] table (or its top level); defaults if None."""
    if path is None:
        return PairParams()
    from services.core.config import from_mapping, load_toml

    data = load_toml(path)
    table = data.get("dynamics", data)
    if not isinstance(table, dict):
        raise UsageError(f"{path}: [dynamics] must be a table")
    return from_mapping(PairParams, table, "dynamics")


def _build_parser() -> Parser:
    parser = Parser(prog=PROG, description="Numerical analysis and statistics (paper Secs 4, 7).")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    cfg = Parser(add_help=False)
    cfg.add_argument(
        "--config",
        metavar="FILE.toml",
        help="dynamics parameters: the file's [dynamics] table (robot, human, a_rh, a_hr) or "
        "its top level; default: SPEC §1 values",
    )

    p = sub.add_parser(
        "thresholds",
        parents=[cfg],
        help="u*, u_d* and the origin's eigenvalues",
        description="Bifurcation thresholds of Sec 4.3.",
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")

    p = sub.add_parser(
        "sweep",
        parents=[cfg],
        help="consensus map over (b_r, b_h) (Fig 3a)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Steady state of eqs 1-2 over a grid of biases (Fig 3a).\n\n"
            "Initial condition: the unopinionated origin with an infinitesimal robot lean,\n"
            "z_r(0) = 1e-6, z_h(0) = 0. (From the exact origin, the flow on the diagonal\n"
            "b_r = b_h never leaves the invariant line z_r = z_h and can end on a saddle; the\n"
            "lean breaks that symmetry as any real perturbation would.)\n"
            "Converged: max(|dz_r/dt|, |dz_h/dt|) < 1e-9 at the reported state; consensus:\n"
            "sgn z_r = sgn z_h. Method 'newton' (default): RK4 at 20 ms, finished by Newton on\n"
            "eqs 4-5 once the state is certified inside the basin of a stable equilibrium\n"
            "(log-norm ball), else integrated to the 20 s horizon. Method 'rk4': the plain\n"
            "baseline, RK4 at 5 ms for 20 s.\n\n"
            "Output .npz arrays: b_r (N), b_h (N), consensus, z_r, z_h, converged (N×N,\n"
            "[i, j] for b_h[i], b_r[j]), z0, method, dt, horizon, tol, params (JSON)."
        ),
    )
    p.add_argument("--grid", type=_grid_size, default=121, metavar="N", help="N×N grid (121)")
    p.add_argument(
        "--range", type=positive_float, default=6.0, metavar="R",
        help="biases in linspace(-R, R, N) (6)",
    )
    p.add_argument("--out", required=True, metavar="FILE.npz", help="where to write the arrays")
    p.add_argument("--png", metavar="FILE.png", help="also draw the map")
    p.add_argument("--method", choices=("newton", "rk4"), default="newton")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")

    p = sub.add_parser(
        "equilibria",
        parents=[cfg],
        help="all equilibria and stability (Fig 3b)",
        description="Every equilibrium of eqs 1-2 at fixed biases, with the "
        "Jacobian's eigenvalues (eq 3) as [re, im] pairs.",
    )
    p.add_argument("--br", type=finite_float, required=True, help="robot bias b_r")
    p.add_argument("--bh", type=finite_float, required=True, help="human bias b_h")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--png", metavar="FILE.png", help="draw the nullclines Δ1 = 0, Δ2 = 0")

    p = sub.add_parser(
        "paper-claims",
        parents=[cfg],
        help="settle three claims of the paper by computation",
        description="(1) whether any paired table with the published phase margins gives the "
        "Stuart-Maxwell statistic 68.125; (2) the diagonal bias above which eqs 1-2 have one "
        "equilibrium (and above which every equilibrium is a consensus) against the paper's "
        "|b| > u; (3) how Fig 3a's consensus map depends on the unstated starting opinion.",
    )
    p.add_argument("--grid", type=_grid_size, default=61, metavar="N", help="Fig 3a grid (61)")
    p.add_argument("--json", action="store_true", help="print JSON")

    p = sub.add_parser(
        "nullclines",
        parents=[cfg],
        help="Fig 3b: the nullclines at b = ±(u + 1) side by side",
        description="Fig 3b in one figure: Δ1 = 0 and Δ2 = 0 (eqs 4-5) with every equilibrium "
        "at b_r = b_h = +(u_r + OFFSET) (panel a) and −(u_r + OFFSET) (panel b). The file's "
        "suffix picks the format (.png, .pdf, .svg).",
    )
    p.add_argument(
        "--offset", type=finite_float, default=1.0, help="bias beyond u_r (1, as Fig 3b)"
    )
    p.add_argument("--out", required=True, metavar="FILE", help="figure to write (.png/.pdf/.svg)")

    p = sub.add_parser(
        "square-claim",
        parents=[cfg],
        help="check the Sec 4.4.1 square claim",
        description="Compare the paper's consensus-square claim (both readings) "
        "with a computed sweep from the same initial condition as `sweep`.",
    )
    p.add_argument("--grid", type=_grid_size, default=121, metavar="N")
    p.add_argument("--range", type=positive_float, default=6.0, metavar="R")
    p.add_argument("--json", action="store_true", help="print JSON instead of a summary")

    p = sub.add_parser(
        "stuart-maxwell",
        help="marginal homogeneity test (Secs 7-8)",
        description="Stuart-Maxwell test; categories empty in both margins are dropped (SPEC §7).",
    )
    p.add_argument(
        "--table",
        required=True,
        metavar="JSON",
        help="square table of counts, rows = first classification, e.g. '[[5,2],[7,4]]'",
    )
    p.add_argument("--json", action="store_true", help="print JSON")

    p = sub.add_parser(
        "bstar",
        help="derive b* = u_r + margin from a press time (SPEC §3 deviation)",
        description="The smallest margin (0.1 grid) for which the robot's arm is on O's side "
        "when a participant who heads straight for O presses PRESS_S after go (default observer, "
        "decision model, Algorithm 2, simulated arm; both options, several jitter seeds).",
    )
    p.add_argument(
        "--press-s", type=positive_float, default=2.2, help="the fastest press to cover (2.2 s)"
    )
    p.add_argument("--seeds", type=int, default=5, help="jitter draws per option (5)")
    p.add_argument("--params", metavar="FILE.toml", help="rig parameters (default: SPEC)")
    p.add_argument("--json", action="store_true", help="print JSON")

    p = sub.add_parser(
        "trial",
        help="one trial as Figs 6-7: ẑ_h, z_r, b_r, θ, d and the hand's path",
        description="Draw one stored trial: opinions, eq 7's θ and d, the hand's path over the "
        "table with the arm's end effector (panels a-d).",
    )
    p.add_argument("--db", required=True, metavar="FILE", help="session database")
    p.add_argument("--session", default=None, help="session id (default: the latest)")
    p.add_argument("--trial", type=int, required=True, help="trial number")
    p.add_argument("--out", required=True, metavar="DIR", help="where to write trial<K>.<fmt>")
    p.add_argument(
        "--format", type=_formats, default=("png",), metavar="FMT",
        help="png, pdf, svg, comma separated (default png)",
    )
    p.add_argument("--params", metavar="FILE.toml", help="the rig's parameters (its layout)")

    p = sub.add_parser(
        "power",
        help="power of a study of N participants (Stuart–Maxwell), from a simulated cohort",
        description="Simulate a population once (offline, --params: e.g. the calibrated "
        "cohort), draw studies of N participants from it with replacement, analyse each as a "
        "real study; power = share of draws where a test is significant, with Wilson 95% "
        "intervals (the Monte-Carlo error).",
    )
    p.add_argument("--participants", default="20,40,60", help="study sizes, e.g. 20,40,60")
    p.add_argument("--runs", type=int, default=100, help="drawn studies per size (100)")
    p.add_argument("--population", type=int, default=400, help="simulated people (400)")
    p.add_argument("--alpha", type=positive_float, default=0.05, help="significance level (0.05)")
    p.add_argument("--seed", type=int, default=1, help="seed of the population and the draws")
    p.add_argument("--params", metavar="FILE.toml", help="cohort parameters (calibrated traits)")
    p.add_argument("--workers", type=int, default=None, help="processes (default: cores)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--out", metavar="DIR", help="write power.json and power.png (and .pdf)")

    p = sub.add_parser(
        "study",
        help="the whole study: Fig 8 and the Sec 7-8 statistics",
        description="Every session of a database: per-trial outcome frequencies (Fig 8a), "
        "control→experiment flows (8b), per-participant grid (8c), contingency table (8d), "
        "Stuart-Maxwell tests (control vs experiment, trials 4→5 … 7→8) and the questionnaire "
        "statistics (t-tests of Q1, Q2, Q4, Q5 vs 5.5; χ² of Q3). Timeouts are excluded from "
        "the categorical tests and listed.",
    )
    p.add_argument("--db", required=True, metavar="FILE", help="session database (nod run)")
    p.add_argument("--json", action="store_true", help="print every number as JSON")
    p.add_argument(
        "--out", metavar="DIR", help="write Figs 8a-8d, report.md and study.json here"
    )
    p.add_argument(
        "--format", type=_formats, default=("png",), metavar="FMT",
        help="figure formats for --out: png, pdf, svg, comma separated (default png)",
    )
    return parser


def _cmd_thresholds(args: argparse.Namespace) -> int:
    from services.analysis.thresholds_report import format_thresholds, thresholds_report

    report = thresholds_report(load_params(args.config))
    print(json.dumps(report, indent=2) if args.json else format_thresholds(report))
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import Progress

    from services.analysis.sweep import bias_grid, save_npz, sweep, sweep_rk4

    p = load_params(args.config)
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


def _cmd_paper_claims(args: argparse.Namespace) -> int:
    from services.analysis.paper_claims import format_report, report

    doc = report(load_params(args.config), args.grid)
    print(json.dumps(doc, indent=2) if args.json else format_report(doc))
    return 0


def _cmd_nullclines(args: argparse.Namespace) -> int:
    from services.analysis.figures import FORMATS
    from services.analysis.plots import plot_nullcline_pair

    suffix = Path(args.out).suffix.lower().lstrip(".")
    if suffix not in FORMATS:
        raise UsageError(f"--out must end in .{', .'.join(FORMATS)}, got {args.out!r}")
    p = load_params(args.config)
    try:
        panels = plot_nullcline_pair(p, args.offset, args.out)
    except OSError as exc:
        raise UsageError(f"cannot write {args.out}: {exc}") from None
    for letter, eqs in zip("ab", panels, strict=True):
        kinds = ", ".join(f"{e.stability} ({e.z_r:+.3f}, {e.z_h:+.3f})" for e in eqs)
        print(f"({letter}) {len(eqs)} equilibria: {kinds}")
    print(f"wrote {args.out}")
    return 0


def _cmd_equilibria(args: argparse.Namespace) -> int:
    from services.analysis.equilibria import find_equilibria

    p = load_params(args.config)
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


def _cmd_square_claim(args: argparse.Namespace) -> int:
    from services.analysis.square_claim import check_square_claim, format_report
    from services.analysis.sweep import bias_grid, sweep

    p = load_params(args.config)
    b = bias_grid(args.grid, args.range)
    report = check_square_claim(sweep(b, b, p), p.robot.u)
    print(json.dumps(report, indent=2) if args.json else format_report(report))
    return 0


def _cmd_stuart_maxwell(args: argparse.Namespace) -> int:
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


def _cmd_study(args: argparse.Namespace) -> int:
    from services.analysis.study import load_study
    from services.analysis.study_report import finite_json, markdown, summary, write_figures

    db = Path(args.db)
    if not db.is_file():
        raise UsageError(f"--db: no such database {args.db!r}; run `nod run` first")
    doc = finite_json(load_study(str(db)))
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
            print(f"wrote {Path(args.out) / 'report.md'}, study.json and 4 figures ({kinds})")
    return 0


def _cmd_bstar(args: argparse.Namespace) -> int:
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


def _cmd_power(args: argparse.Namespace) -> int:
    import os
    import time

    from services.analysis.power import TESTS, plot, population, power
    from services.core.config import load_params

    try:
        sizes = [int(x) for x in args.participants.split(",") if x.strip()]
    except ValueError:
        raise UsageError(
            f"--participants must be sizes like 20,40,60, got {args.participants!r}"
        ) from None
    if not sizes or min(sizes) < 2 or max(sizes) > 10_000:
        raise UsageError("--participants: sizes between 2 and 10000")
    if not (1 <= args.runs <= 100_000 and 10 <= args.population <= 1_000_000 and args.alpha < 1):
        raise UsageError("--runs 1-100000, --population 10-1000000, --alpha in (0, 1)")
    cfg = load_params(args.params)
    t0 = time.monotonic()
    pop = population(cfg, args.population, args.seed, args.workers or os.cpu_count() or 1)
    results = power(pop, sizes, args.runs, args.alpha, args.seed)
    doc = {
        "method": "one simulated population, studies drawn with replacement",
        "population": args.population,
        "alpha": args.alpha,
        "params": args.params,
        "seconds": round(time.monotonic() - t0, 1),
        "results": results,
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
    print(f"power at α = {args.alpha} ({args.runs} drawn studies per size from "
          f"{args.population} simulated people, {doc['seconds']} s):")
    print("  N   " + "  ".join(f"{t.replace('trial_', ''):>22}" for t in TESTS))
    for r in results:
        cells = [
            f"{r['power'][t]:.2f} [{r['ci95'][t][0]:.2f}-{r['ci95'][t][1]:.2f}]" for t in TESTS
        ]
        print(f"  {r['participants']:<4}" + "  ".join(f"{c:>22}" for c in cells))
    return 0


def _cmd_trial(args: argparse.Namespace) -> int:
    from services.analysis.trial_plot import figure
    from services.core.config import load_params
    from services.store import Store

    formats = args.format
    db = Path(args.db)
    if not db.is_file():
        raise UsageError(f"--db: no such database {args.db!r}")
    store = Store(db)
    try:
        trials = store.trials(args.session)
        if not trials:
            raise UsageError(f"no trials for session {args.session or '(latest)'}")
        session = trials[0][0]
        match = [t for _, t in trials if t.trial == args.trial]
        if not match:
            raise UsageError(f"session {session} has no trial {args.trial}")
        samples = store.samples(session, args.trial)
    finally:
        store.close()
    rec = match[0]
    option = f", O={rec.option}" if rec.option else ""
    title = (
        f"session {session}, trial {rec.trial} ({rec.mode}{option}): human {rec.human or '-'}, "
        f"robot {rec.robot or '-'}, outcome {rec.outcome or '-'}"
    )
    layout = load_params(args.params).layout
    try:
        paths = figure(samples, rec, layout, title, Path(args.out), formats)
    except OSError as exc:
        raise UsageError(f"cannot write to --out {args.out!r}: {exc}") from None
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


_COMMANDS = {
    "trial": _cmd_trial,
    "power": _cmd_power,
    "bstar": _cmd_bstar,
    "thresholds": _cmd_thresholds,
    "sweep": _cmd_sweep,
    "equilibria": _cmd_equilibria,
    "nullclines": _cmd_nullclines,
    "paper-claims": _cmd_paper_claims,
    "square-claim": _cmd_square_claim,
    "stuart-maxwell": _cmd_stuart_maxwell,
    "study": _cmd_study,
}


def main(argv: list[str] | None = None) -> int:
    """Run `nod analyze <command> …`; returns the exit code (2 for any bad input)."""
    parser = _build_parser()
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.command is None:
        parser.error(f"choose a command: {', '.join(_COMMANDS)} (see --help)")
    from services.core.config import ConfigError

    try:
        return _COMMANDS[args.command](args)
    except (UsageError, ConfigError, ValueError) as exc:
        return fail(f"{PROG} {args.command}", f"error: {exc}")


if __name__ == "__main__":
    raise SystemExit(main())
