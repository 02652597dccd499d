"""`nod analyze …`: thin command-line shell over the analysis library.

Subcommands: thresholds (Sec 4.3), sweep (Fig 3a), equilibria (Fig 3b), nullclines (Fig 3b, both
panels), paper-claims and square-claim (Sec 4.4.1), stuart-maxwell (Secs 7-8), study (Secs 7-8,
Fig 8), trial (Figs 6-7), power (study size), bstar (the b* margin). Every bad input ends with
one line on stderr, `nod analyze <sub>: error: <what and how to fix>`, and exit code 2.
"""

from __future__ import annotations

import argparse
import sys

from services.analysis.commands import COMMANDS, UsageError
from services.analysis.multiplicity import CORRECTIONS
from services.compute.engine import add_engine_args
from services.core.cli import SEED, Parser, fail, finite_float, int_in, positive_float

PROG = "nod analyze"


def _formats(text: str) -> tuple[str, ...]:
    from services.analysis.figures import parse_formats

    try:
        return parse_formats(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _build_parser() -> Parser:
    parser = Parser(prog=PROG, description="Numerical analysis and statistics (paper Secs 4, 7).")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    cfg = Parser(add_help=False)
    cfg.add_argument(
        "--params",
        metavar="FILE.toml",
        help="parameters overriding SPEC (deploy/params.example.toml): the dynamics are its "
        "[decision.pair] (robot, human, a_rh, a_hr); default: SPEC §1 values",
    )

    p = sub.add_parser(
        "thresholds",
        parents=[cfg],
        help="u*, u_d* and the origin's eigenvalues",
        description="Bifurcation thresholds of Sec 4.3. With --options N (N > 2) or --beta / "
        "--delta: the N-option model's agreement and disagreement points, each with the "
        "eigenvalues it comes from (docs/multi-option.md).",
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument(
        "--options", type=int_in(2, 64), default=2, metavar="N",
        help="number of options N_o (default 2: the paper's two-option report)",
    )
    p.add_argument(
        "--beta", type=finite_float, default=0.0,
        help="weight of an agent's own opinion of the other options (multi-option β; 0)",
    )
    p.add_argument(
        "--delta", type=finite_float, default=0.0,
        help="weight of the neighbour's opinion of the other options (multi-option δ; 0)",
    )

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
    p.add_argument("--grid", type=int_in(2), default=121, metavar="N", help="N×N grid (121)")
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
    p.add_argument("--grid", type=int_in(2), default=61, metavar="N", help="Fig 3a grid (61)")
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
    p.add_argument("--grid", type=int_in(2), default=121, metavar="N")
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
    p.add_argument("--seeds", type=int_in(1, 1000), default=5, help="jitter draws per option (5)")
    p.add_argument("--params", metavar="FILE.toml", help="rig parameters (default: SPEC)")
    p.add_argument("--json", action="store_true", help="print JSON")

    p = sub.add_parser(
        "trial",
        help="one trial as Figs 6-7: ẑ_h, z_r, b_r, θ, d and the hand's path",
        description="Draw one stored trial: opinions, eq 7's θ and d, the hand's path over the "
        "table with the arm's end effector (panels a-d).",
    )
    p.add_argument("--db", required=True, metavar="FILE", help="session database")
    who = p.add_mutually_exclusive_group()
    who.add_argument(
        "--participant", default=None, metavar="ID",
        help="the participant's latest session with trials (e.g. P01)",
    )
    who.add_argument(
        "--session", default=None, metavar="ID",
        help="a session id, or a participant id (default: the latest session)",
    )
    p.add_argument("--trial", type=int_in(1, 10_000), required=True, help="trial number")
    p.add_argument("--out", required=True, metavar="DIR", help="where to write trial<K>.<fmt>")
    p.add_argument(
        "--format", type=_formats, default=("png",), metavar="FMT",
        help="png, pdf, svg, comma separated (default png)",
    )
    p.add_argument("--params", metavar="FILE.toml", help="the rig's parameters (its layout)")

    p = sub.add_parser(
        "power",
        help="power of a study of N participants (Stuart–Maxwell), from simulated populations",
        description="Simulate K independent populations (offline, on the compute engine; "
        "--params: e.g. the calibrated cohort), draw studies of N distinct participants from "
        "each, analyse each as a real study; power = share of significant draws pooled over "
        "the populations, at the --correction and uncorrected (the paper's), with a 95% "
        "interval over the populations (Monte-Carlo error and the spread between populations), "
        "beside the power the paper's own statistics imply (noncentral χ²). The default "
        "(6 × 200 people) simulates 1200 sessions: about a minute on 2 cores.",
    )
    p.add_argument("--participants", default="20,40,51,60",
                   help="study sizes, e.g. 20,40,60 (default 20,40,51,60: 51 is the paper's)")
    p.add_argument("--runs", type=int_in(1, 10**5), default=100,
                   help="drawn studies per size and population (100)")
    p.add_argument("--populations", type=int_in(1, 1000), default=6,
                   help="independent populations (6; at least 2 for an interval that holds "
                   "their spread)")
    p.add_argument("--population", type=int_in(1, 10**6), default=200,
                   help="simulated people per population (200; at least the largest N)")
    p.add_argument("--alpha", type=positive_float, default=0.05, help="significance level (0.05)")
    p.add_argument(
        "--correction", choices=CORRECTIONS, default="holm",
        help="adjust each drawn study's p-values as `nod analyze study` does (default holm); "
        "the uncorrected p (the paper's) are reported beside it",
    )
    p.add_argument("--seed", type=SEED, default=1,
                   help="first seed (population j: seeds seed + j·size …) and the draws' seed")
    p.add_argument("--params", metavar="FILE.toml",
                   help="cohort parameters (default: the person fitted to the paper)")
    add_engine_args(p)
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--out", metavar="DIR", help="write power.json and power.png (and .pdf)")

    p = sub.add_parser(
        "policies",
        help="two robots' cohorts compared: C and C+CH on O per trial and kind, and power",
        description="Compare a cohort of the paper's robot with one of another policy (each "
        "store one condition, `nod cohort --policy`): per consensus trial and over trials "
        "4-8, the share that ends on O without a switch (C) and in agreement (C+CH), the time "
        "to an agreed trial's end, per kind of person where the store knows it, each with a "
        "95%% bootstrap interval over participants; and the power of a between-subjects study "
        "of the two robots at N per robot (docs/adaptive.md).",
    )
    p.add_argument("paper_db", metavar="DB_PAPER", help="the paper's robot's cohort")
    p.add_argument("adaptive_db", metavar="DB_ADAPTIVE", help="the other robot's cohort")
    p.add_argument("--participants", default="20,40,60",
                   help="study sizes per robot for the power (default 20,40,60)")
    p.add_argument("--bootstrap", type=int_in(100, 10**6), default=2000,
                   help="bootstrap resamples (2000)")
    p.add_argument("--runs", type=int_in(10, 10**6), default=1000,
                   help="drawn studies per size for the power (1000)")
    p.add_argument("--alpha", type=positive_float, default=0.05, help="significance level")
    p.add_argument("--seed", type=SEED, default=1, help="the resampling's seed")
    p.add_argument("--json", action="store_true", help="print every number as JSON")

    p = sub.add_parser(
        "study",
        help="the whole study: Fig 8 and the Sec 7-8 statistics",
        description="Every session of a database: per-trial outcome frequencies (Fig 8a), "
        "control→experiment flows (8b), per-participant grid (8c), contingency table (8d), "
        "Stuart-Maxwell tests (control vs experiment, trials 4→5 … 7→8) and the questionnaire "
        "statistics (t-tests of Q1, Q2, Q4, Q5 vs 5.5; χ² of Q3). Only complete sessions "
        "count unless --min-trials says otherwise; every excluded session is listed with its "
        "reason. Timeouts and interrupted trials are excluded from the categorical tests and "
        "listed. The Stuart-Maxwell p-values are corrected for multiple comparisons (Holm).",
    )
    p.add_argument(
        "--db", required=True, action="append", metavar="FILE",
        help="session database (nod run); repeat it to analyse several rigs' stores as one study "
        "(a participant id in two stores or on two rigs is refused)",
    )
    p.add_argument(
        "--min-trials", type=int_in(1, 10_000), default=None, metavar="N",
        help="include any session with at least N scored trials (default: complete sessions "
        "only: status complete, every scheduled trial stored)",
    )
    p.add_argument(
        "--correction", choices=CORRECTIONS, default="holm",
        help="multiple-comparison correction of the Stuart-Maxwell tests (default holm)",
    )
    p.add_argument(
        "--include-withdrawn", action="store_true",
        help="analyse participants who withdrew too (default: left out, and named in one line)",
    )
    p.add_argument(
        "--mixed-params", action="store_true",
        help="pool sessions whose provenance says they ran different parameters (default: "
        "refused, the sessions of each params hash named in one line)",
    )
    p.add_argument("--json", action="store_true", help="print every number as JSON")
    p.add_argument(
        "--out", metavar="DIR",
        help="write Figs 8a-8d, the option shares, report.md and study.json here",
    )
    p.add_argument(
        "--options", metavar="NAMES", default=None,
        help="the option set to analyse, comma separated, e.g. red,blue,green (default: the "
        "only one stored, else the paper's red,blue); sessions of another set are listed as "
        "excluded",
    )
    p.add_argument(
        "--format", type=_formats, default=("png",), metavar="FMT",
        help="figure formats for --out: png, pdf, svg, comma separated (default png)",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run `nod analyze <command> …`; returns the exit code (2 for any bad input)."""
    parser = _build_parser()
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.command is None:
        parser.error(f"choose a command: {', '.join(COMMANDS)} (see --help)")
    from services.core.config import ConfigError
    from services.store.store import StoreError

    try:
        return COMMANDS[args.command](args)
    except (UsageError, ConfigError, ValueError, StoreError) as exc:  # StoreError: a damaged db
        return fail(f"{PROG} {args.command}", f"error: {exc}")


if __name__ == "__main__":
    raise SystemExit(main())
