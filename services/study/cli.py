"""`nod study …`: a study's roster — make it, record consent, see who is next, run their session.

    nod study init STUDY.toml --participants 40 [--seed S] [--params FILE] [--options N]
                   [--policies paper,adaptive [--assignment counterbalanced|random]]
    nod study consent STUDY.toml --db DB --participant P07 --yes [--age 25-34 --handedness right]
    nod study withdraw STUDY.toml --db DB --participant P07 [--reason TEXT]
                       [--delete|--aggregate|--keep]
    nod study next STUDY.toml --db DB
    nod study start STUDY.toml --db DB [--participant P07] [--again WHY] [--sim] [-- FLAGS…]
    nod study status STUDY.toml --db DB [--json]

`start` runs `nod experiment` (or, with --sim, `nod run --sim`) for the participant with their
order (`--order`), the study's `--params` (and `--options N` for a study of N options: its
file's `options`), their condition's `--policy` (a study file's `[conditions] policies`: robot
policies between subjects, `services.study.conditions`), and any FLAGS after `--` (the rig's
`--connect`, `--rig`, `--clicks` …); it refuses a participant without consent and one who
already has a session (unless `--again` says why). `withdraw` (and `consent --no` for someone
who had consented or has data) records a withdrawal, by whom (user@host): they are left out of
every export, analysis and fit, and with `--delete` (or the study's `on_withdrawal = "delete"`)
their data is deleted, with `--aggregate` (`on_withdrawal = "aggregate"`) deleted after their
trials' outcomes are added to the study's anonymous counts (`services.store.withdrawals`).
Every refusal is one line on stderr with exit code 2.
"""

from __future__ import annotations

import argparse
import json
import secrets
import shlex
import signal
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path
from types import FrameType

from services.core.cli import SEED, Parser, add_options_arg, fail, int_in
from services.core.config import load_with_options
from services.core.lifeline import nod_command
from services.model.counterbalance import letters
from services.model.geometry import COLOURS
from services.model.protocol import TrialSpec
from services.model.schedule import OptionsSchedule, OptionsTrial
from services.store import Store
from services.store.participants import consent_of, record_consent, reuse_problem
from services.store.withdrawals import (
    Deletion,
    delete_participant,
    operator_id,
    personal_rows,
    record_withdrawal,
    recording_files,
    withdrawal_problem,
    withdrawals,
)
from services.study.conditions import (
    ASSIGNMENTS,
    ConditionsError,
    PolicyConditions,
    check_files,
    identity,
    is_built_in,
)
from services.study.roster import Roster, Standing, roster
from services.study.studyfile import (
    MAX_PARTICIPANTS,
    Conditions,
    Study,
    StudyError,
    load,
    make_study,
    write,
)

PROG = "nod study"
AGES = ("18-24", "25-34", "35-44", "45-54", "55-64", "65+", "undisclosed")
HANDS = ("right", "left", "ambidextrous", "undisclosed")
# Flags `start` sets itself: given again after `--` they would contradict the study.
RESERVED = ("--db", "--participant", "--participants", "--order", "--again", "--resume",
            "--options", "--study")


def build_parser() -> Parser:
    """The command line of `nod study`."""
    p = Parser(prog=PROG, description="A study's roster: counterbalanced orders, consent, "
               "who is next, and their session (docs/study.md).")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser, required=True)

    def command(name: str, help_: str, db: bool = True) -> Parser:
        c: Parser = sub.add_parser(name, help=help_, description=help_)
        c.add_argument("study", type=Path, metavar="STUDY.toml", help="the study file")
        if db:
            c.add_argument("--db", type=Path, default=Path("nod-sessions.sqlite"),
                           help="session store (default nod-sessions.sqlite)")
        return c

    c = command("init", "write a new study file with a counterbalanced roster", db=False)
    c.add_argument("--participants", type=int_in(1, MAX_PARTICIPANTS), required=True,
                   help="how many participants (slots 1..N)")
    c.add_argument("--seed", type=SEED, default=None,
                   help="seed of the roster's shuffle (default: a random one, stored in the file)")
    c.add_argument("--name", default=None, help="the study's name (default: the file's stem)")
    c.add_argument("--params", type=Path, default=None,
                   help="the protocol's parameters file every session runs (default: SPEC)")
    add_options_arg(c)  # the study's option set: the params file's list, or N default names
    c.add_argument("--prefix", default="P", help="participant ids <prefix>01, … (default P)")
    c.add_argument("--policies", default=None, metavar="NAME[=POLICY],…",
                   help="robot policies as conditions between subjects, one per participant: "
                   "each a condition's name, with its --policy (paper, adaptive or a policy "
                   "file) after = unless the name is a built-in's (e.g. paper,adaptive or "
                   "paper,tuned=tuned.toml)")
    c.add_argument("--assignment", choices=ASSIGNMENTS, default=None,
                   help="with --policies: counterbalanced over the roster's orders (default) or "
                   "random (seeded by --seed)")
    c.add_argument("--force", action="store_true", help="overwrite an existing study file")

    c = command("consent", "record a participant's consent (and optional demographics)")
    c.add_argument("--participant", required=True, help="the participant's id in the study")
    yes_no = c.add_mutually_exclusive_group(required=True)
    yes_no.add_argument("--yes", action="store_true", help="consent given")
    yes_no.add_argument("--no", action="store_true", help="consent refused or withdrawn")
    c.add_argument("--age", choices=AGES, default=None, help="age range")
    c.add_argument("--handedness", choices=HANDS, default=None, help="handedness")
    c.add_argument("--notes", default=None, help="free-text notes (keep them non-identifying)")
    _policy(c, "with --no for someone who had consented or has data: ")

    c = command("withdraw", "a participant withdraws: left out of every export, analysis and "
                "fit; with --delete their data is deleted")
    c.add_argument("--participant", required=True, help="the participant's id in the study")
    c.add_argument("--reason", default="", help="why, optional (keep it non-identifying; not "
                   "kept if their data is deleted)")
    _policy(c, "")
    c.add_argument("--dry-run", action="store_true",
                   help="print what would be deleted, change nothing")

    command("next", "who is next, with their order (exit 1: nobody is left)")

    c = command("start", "start the next (or a named) participant's session with their order")
    c.add_argument("--participant", default=None, help="this participant (default: the next)")
    c.add_argument("--again", default=None, metavar="WHY",
                   help="a new session for a participant who has one; the reason is stored")
    c.add_argument("--sim", action="store_true",
                   help="a simulated participant: `nod run --sim` (router and every service)")
    c.add_argument("--dry-run", action="store_true", help="print the command, run nothing")

    c = command("status", "who is done, running, aborted and left")
    c.add_argument("--json", action="store_true", help="print the roster as JSON")
    return p


def _policy(c: argparse.ArgumentParser, when: str) -> None:
    how = c.add_mutually_exclusive_group()
    how.add_argument("--delete", action="store_true", help=f"{when}delete their sessions, "
                     "trials, samples, answers, fits, recordings … (default: the study file's "
                     "on_withdrawal, keep unless it says delete or aggregate)")
    how.add_argument("--aggregate", action="store_true", help=f"{when}as --delete, keeping "
                     "only their trials' outcomes in the study's anonymous per-trial counts")
    how.add_argument("--keep", action="store_true",
                     help=f"{when}keep their data, left out of exports, analyses and fits")


def main(argv: list[str] | None = None) -> int:
    """Run one `nod study` command."""
    args_in = list(sys.argv[1:] if argv is None else argv)
    extra: list[str] = []
    if "--" in args_in:  # the conductor's own flags, for `start`
        at = args_in.index("--")
        args_in, extra = args_in[:at], args_in[at + 1 :]
    args = build_parser().parse_args(args_in)
    prog = f"{PROG} {args.command}"
    if extra and args.command != "start":
        return fail(prog, "flags after -- are for `nod study start` only")
    try:
        if args.command == "init":
            return _init(args)
        study = load(args.study)
        trials = _protocol(study)
        store = Store(args.db)
    except (StudyError, OSError, ValueError) as exc:
        return fail(prog, exc)
    try:
        if args.command == "consent":
            return _consent(args, study, store)
        if args.command == "withdraw":
            return _withdraw(args, study, store)
        if args.command == "next":
            return _next(args, study, roster(study, store))
        if args.command == "status":
            return _status(args, roster(study, store), len(trials))
        cmd = _start_command(args, study, store, extra)
    except StudyError as exc:
        return fail(prog, exc)
    finally:
        store.close()
    if isinstance(cmd, str):
        return fail(prog, cmd)
    print(f"nod study: {shlex.join(['nod', *cmd])}", flush=True)
    if args.dry_run:
        return 0
    return _run(nod_command(*cmd))


def _protocol(study: Study) -> tuple[TrialSpec, ...] | tuple[OptionsTrial, ...]:
    """The study's schedule, checked against the conditions and options the file was made for."""
    try:
        # the params file's own option set (checked below), else the default names of N
        n = None if study.paper or study.params is not None else len(study.options)
        cfg, schedule = load_with_options(study.params, n)
    except (ValueError, OSError) as exc:
        raise StudyError(f"the study's params: {exc}") from None
    names = COLOURS if schedule is None else schedule.names
    if names != study.options:
        source = study.params or "the default names"
        raise StudyError(
            f"the study file's options {list(study.options)} are not those of {source} "
            f"{list(names)}: give the study the params it was made for"
        )
    trials = cfg.protocol.trials if schedule is None else schedule.trials
    have = Conditions.of(trials)
    if have != study.conditions:
        source = study.params or "the SPEC defaults"
        raise StudyError(
            f"the study file's conditions ({study.conditions.describe()}) are not the protocol "
            f"of {source} ({have.describe()}): give the study the params it was made for"
        )
    return trials


def _init(args: argparse.Namespace) -> int:
    prog = f"{PROG} init"
    path: Path = args.study
    if path.exists() and not args.force:
        return fail(prog, f"{path} exists: a roster in use is not overwritten (--force to do so)")
    seed = args.seed if args.seed is not None else secrets.randbelow(2**31)
    if args.assignment is not None and args.policies is None:
        return fail(prog, "--assignment goes with --policies (the conditions it assigns)")
    try:
        policies = None if args.policies is None else _policies_arg(
            args.policies, args.assignment or "counterbalanced")
        cfg, schedule = load_with_options(args.params, args.options)
        protocol: tuple[TrialSpec, ...] | OptionsSchedule = (
            cfg.protocol.trials if schedule is None else schedule)
        params = None if args.params is None else args.params.resolve()
        study = make_study(args.name or path.stem, protocol, args.participants, seed, params,
                           args.prefix, policies)
        if policies is not None:
            check_files(policies)
        write(study, path)
    except (StudyError, ConditionsError, ValueError, OSError) as exc:
        return fail(prog, exc)
    cb, n = study.counterbalance, len(study.participants)
    first, last = study.participants[0].id, study.participants[-1].id
    print(f"{path}: {n} participants {first}–{last}, {study.conditions.describe()}")
    how = ("with colour reversal" if study.paper else
           f"with the {len(cb.options)} cyclic relabellings of {', '.join(cb.options)}")
    print(f"O orders: a Latin square of {_letters(study)} {how}, in blocks of "
          f"{cb.block} (seed {cb.seed}); the gaze looks toward O")
    if n % cb.block:
        every = "every even count" if study.paper else f"every multiple of {len(cb.options)}"
        print(f"note: the last block has {n % cb.block} of {cb.block} participants; every "
              f"position is balanced over full blocks (and {every} within one)")
    if (pc := study.policy_conditions) is not None:
        counts = ", ".join(f"{name} {sum(e.condition == name for e in study.participants)}"
                           for name in pc.names)
        how = (f"counterbalanced: each order once in each condition over every {len(pc.names)} "
               f"blocks of {cb.block}" if pc.assignment == "counterbalanced" else
               f"random, seeded by {cb.seed}")
        print(f"robot policies between subjects: {counts} participants ({how})")
    return 0


def _policies_arg(text: str, assignment: str) -> PolicyConditions:
    """`--policies paper,tuned=tuned.toml`: the conditions, files' paths absolute."""
    pairs = []
    for item in text.split(","):
        name, _, value = item.strip().partition("=")
        value = value.strip() or name.strip()
        pairs.append((name.strip(), value if is_built_in(value) else str(Path(value).resolve())))
    pc = PolicyConditions(tuple(pairs), assignment)  # type: ignore[arg-type]
    pc.check()
    return pc


def _consent(args: argparse.Namespace, study: Study, store: Store) -> int:
    prog, pid = f"{PROG} consent", args.participant
    if study.entry(pid) is None:
        return fail(prog, _not_in(study, pid))
    if args.yes and (args.delete or args.keep or args.aggregate):
        return fail(prog, "--delete, --aggregate and --keep go with --no (a withdrawal)")
    if args.yes and (problem := withdrawal_problem(store, pid)):
        return fail(prog, problem)
    before = consent_of(store, pid)
    demographics = {k: v for k, v in (("age", args.age), ("handedness", args.handedness),
                                      ("notes", args.notes)) if v is not None}
    record_consent(store, pid, bool(args.yes), time.time_ns(), demographics)
    extra = "".join(f"; {k} {v}" for k, v in demographics.items())
    if args.yes:
        print(f"{pid}: consent given ({_when(time.time_ns())}){extra}")
        return 0
    data = set(personal_rows(store, pid)) - {"participants"}  # the row just written aside
    had = (before is not None and before.consent) or bool(data)
    if not had:  # nothing given, nothing stored: a refusal, not a withdrawal
        print(f"{pid}: consent refused: no session will start ({_when(time.time_ns())}){extra}")
        return 0
    return _withdraw_now(args, study, store, pid, "consent withdrawn")


def _withdraw(args: argparse.Namespace, study: Study, store: Store) -> int:
    pid = args.participant
    if study.entry(pid) is None and not personal_rows(store, pid):
        return fail(f"{PROG} withdraw", _not_in(study, pid))
    return _withdraw_now(args, study, store, pid, args.reason)


def _withdraw_now(
    args: argparse.Namespace, study: Study, store: Store, pid: str, reason: str
) -> int:
    """Record the withdrawal and, by the study's policy or the flags, delete their data."""
    policy = ("keep" if args.keep else "delete" if args.delete else
              "aggregate" if args.aggregate else study.on_withdrawal)
    delete, aggregate = policy != "keep", policy == "aggregate"
    before = withdrawals(store).get(pid)
    if getattr(args, "dry_run", False):
        rows = personal_rows(store, pid)
        files, shared = recording_files(store, pid)
        what = ", ".join(f"{n} {t}" for t, n in sorted(rows.items())) or "no rows"
        act = ("would keep (left out of exports, analyses, fits)" if not delete else
               "would add their trials to the anonymous counts and delete" if aggregate else
               "would delete")
        print(f"{pid}: {act}: {what}; recording files: "
              f"{', '.join(map(str, files)) or 'none'}"
              + (f" (kept, shared: {', '.join(map(str, shared))})" if shared else ""))
        return 0
    now = time.time_ns()
    if before is not None and before.deleted:
        print(f"{pid}: withdrawn ({_when(before.withdrawn_ns)}), data deleted "
              f"({_when(before.deleted_ns or before.withdrawn_ns)}): nothing left to do")
        return 0
    by = operator_id()
    w = record_withdrawal(store, pid, now, reason, by)
    when = f"withdrawn ({_when(w.withdrawn_ns)})" + (f", reason: {w.reason}" if w.reason else "")
    if not delete:
        again = " already" if before is not None else ""
        print(f"{pid}:{again} {when}; data kept, left out of nod export, nod analyze study and "
              "nod fit (--include-withdrawn keeps them); never started or resumed again")
        return 0
    gone = delete_participant(store, pid, now, by, aggregate)
    print(_deleted_line(pid, gone))
    if gone.failed:
        print(f"{PROG}: could not delete {len(gone.failed)} recording file(s) of {pid}; "
              "delete them by hand: " + ", ".join(f"{p} ({why})" for p, why in gone.failed),
              file=sys.stderr)
        return 1
    return 0


def _deleted_line(pid: str, d: Deletion) -> str:
    rows = {k: v for k, v in d.withdrawal.counts.items()
            if k not in ("recording_files", "aggregate_trials")}
    what = ", ".join(f"{n} {t}" for t, n in sorted(rows.items())) or "no rows"
    if d.withdrawal.aggregated:
        what = (f"{d.withdrawal.counts.get('aggregate_trials', 0)} trial outcome(s) added to the "
                f"anonymous counts (withdrawn_aggregates), then {what}")
    files = f"{len(d.removed)} recording file(s) deleted"
    if d.missing:
        files += f", {len(d.missing)} already gone"
    if d.kept:
        files += f", {len(d.kept)} kept (another session's too: {', '.join(map(str, d.kept))})"
    backup = ("" if d.backup is None else f"; backup {d.backup} rewritten without them"
              if d.backup_error is None else f"; backup NOT rewritten ({d.backup_error})")
    return (f"{pid}: withdrawn, data deleted in one transaction: {what}; {files}{backup}; the "
            f"withdrawal stays recorded (id, times, counts, by {d.withdrawal.by or 'unknown'}); "
            "copies made elsewhere are yours to delete")


def _next(args: argparse.Namespace, study: Study, r: Roster) -> int:
    nxt = r.next()
    if nxt is None:
        print(f"study {study.name}: nobody is left ({_counts(r)})")
        return 1
    print(_describe(study, nxt))
    if nxt.consent is None:
        print(f"consent: not recorded — nod study consent {shlex.quote(str(args.study))} "
              f"--db {shlex.quote(str(args.db))} --participant {nxt.entry.id} --yes")
    return 0


def _start_command(
    args: argparse.Namespace, study: Study, store: Store, extra: list[str]
) -> list[str] | str:
    """The `nod …` command for the participant's session, or why it may not start."""
    r = roster(study, store)
    if args.participant is not None:
        who = r.standing(args.participant)
        if who is None:
            return _not_in(study, args.participant)
    else:
        who = r.next()
        if who is None:
            return f"nobody is left in study {study.name} ({_counts(r)})"
    pid = who.entry.id
    if problem := withdrawal_problem(store, pid):
        return problem
    if who.consent is None:
        return (f"{pid} has no consent on record: nod study consent {args.study} --db {args.db} "
                f"--participant {pid} --yes")
    if not who.consent.consent:
        return f"{pid} refused or withdrew consent ({_when(who.consent.consented_ns)})"
    if args.again is not None and not args.again.strip():
        return "--again needs a reason, e.g. --again 'fire alarm at trial 5'"
    if args.again is None and (problem := reuse_problem(store, pid)):
        return problem
    reserved = (RESERVED + (("--params",) if study.params is not None else ())
                + (("--policy",) if study.policy_conditions is not None else ()))
    for flag in extra:
        if flag.split("=", 1)[0] in reserved:
            return f"{flag.split('=', 1)[0]} after -- : the study sets it (give --db before --)"
    cmd = ["run", "--sim"] if args.sim else ["experiment"]
    cmd += ["--db", str(args.db), "--participant", pid, "--order", study.order_arg(who.entry),
            "--study", str(args.study)]
    if study.params is not None:
        cmd += ["--params", str(study.params)]
    if not study.paper:  # a table of N boxes (a params file's list must agree: it is checked)
        cmd += ["--options", str(len(study.options))]
    if (policy := study.policy_arg(who.entry)) is not None:  # their condition's robot
        cmd += ["--policy", policy]
    if args.again is not None:
        cmd += ["--again", args.again]
    if args.sim and not any(f.split("=", 1)[0] == "--seed" for f in extra):
        cmd += ["--seed", str(who.entry.slot)]  # one simulated person per slot
    print(_describe(study, who), flush=True)
    return cmd + extra


def _run(cmd: list[str]) -> int:
    """Run the session in the foreground; its exit code.

    Ctrl-C reaches the child from the terminal, which stops cleanly (and says how to resume);
    this process waits for it rather than dying first. A SIGTERM is passed on.
    """
    proc = subprocess.Popen(cmd)

    def forward(_sig: int, _frame: FrameType | None) -> None:
        proc.terminate()

    old_int = signal.signal(signal.SIGINT, signal.SIG_IGN)  # after the exec: the child's own
    old_term = signal.signal(signal.SIGTERM, forward)
    try:
        return proc.wait()
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)


def _status(args: argparse.Namespace, r: Roster, n_trials: int) -> int:
    if args.json:
        print(json.dumps(r.as_json(), indent=2))
        return 0
    study, cb = r.study, r.study.counterbalance
    how = (f"Latin square of {_letters(study)} in blocks of {cb.block} (seed {cb.seed})"
           if cb.method == "latin-square" else "declared orders")
    print(f"study {study.name}: {len(study.participants)} participants, "
          f"{study.conditions.describe()}, {how}")
    pc = study.policy_conditions
    if pc is not None:
        listed = ", ".join(f"{name} (--policy {value})" for name, value in pc.policies)
        print(f"conditions between subjects ({pc.assignment}): {listed}")
    width = max((len(n) for n in pc.names), default=0) if pc is not None else 0
    head = f"{'condition':<{max(width, 9)}}  " if pc is not None else ""
    print(f"{'slot':>4}  {'id':<8} {'consent':<8} {'status':<9} {'trials':>6}  "
          f"{'session':<12}  {head}O")
    expected = _identities(study)
    for s in r.standings:
        last = s.session
        consent = "—" if s.consent is None else ("yes" if s.consent.consent else "no")
        trials = f"{last.trials}/{n_trials}" if last else ""
        cond = f"{s.entry.condition or '':<{max(width, 9)}}  " if pc is not None else ""
        print(f"{s.entry.slot:>4}  {s.entry.id:<8} {consent:<8} {s.status:<9} {trials:>6}  "
              f"{last.session if last else '':<12}  {cond}{study.order_arg(s.entry)}"
              f"{_note(s, study, expected)}")
    nxt = r.next()
    print(f"{_counts(r)}; next: {nxt.entry.id if nxt else 'nobody'}")
    if pc is not None:
        finished = [s.entry.condition for s in r.standings if s.status == "done"]
        print("done per condition: " + ", ".join(f"{name} {finished.count(name)}"
                                                 for name in pc.names))
    done = r.balance()
    if done and study.paper:
        reds = " ".join(f"{red}/{red + blue}" for red, blue in done)
        print(f"red O per consensus trial {list(study.conditions.consensus)} among the done: "
              f"{reds}")
    elif done:
        per = " ".join("/".join(map(str, counts)) for counts in done)
        print(f"O = {'/'.join(study.options)} per consensus trial "
              f"{list(study.conditions.consensus)} among the done: {per}")
    if r.strangers:
        who = ", ".join(f"{p} ({n})" for p, n in sorted(r.strangers.items()))
        print(f"sessions in {args.db} of participants not in the study: {who}")
    return 0


def _identities(study: Study) -> dict[str, tuple[str, str]]:
    """(name, SHA-256) each condition's policy stores with a session (none: a file unreadable)."""
    pc, out = study.policy_conditions, {}
    for name, value in () if pc is None else pc.policies:
        try:
            out[name] = identity(value)
        except ValueError:
            continue
    return out


def _note(s: Standing, study: Study, expected: dict[str, tuple[str, str]] | None = None) -> str:
    notes = []
    last = s.session
    policy = study.policy_arg(s.entry)
    with_policy = "" if policy is None else f" --policy {shlex.quote(policy)}"
    if s.withdrawal is not None:
        data = "data deleted" if s.withdrawal.deleted else "data kept, left out"
        notes.append(f"withdrew {_when(s.withdrawal.withdrawn_ns)}, {data}")
    if s.status in ("running", "aborted") and last is not None:
        notes.append(f"resume: nod experiment --resume {last.session}{with_policy}, or nod run "
                     f"--sim --resume {last.session}{with_policy} if simulated")
    if len(s.sessions) > 1:
        notes.append(f"{len(s.sessions)} sessions")
    if s.order_mismatch and last is not None and last.options is not None:
        notes.append(f"ran {letters(last.options, study.options)}, not the roster's")
    want = (expected or {}).get(s.entry.condition or "")
    if want is not None and last is not None and s.policy_ran != want:
        ran = s.policy_ran
        what = "no robot policy" if ran is None else f"the policy {ran[0]} ({ran[1][:12]})"
        notes.append(f"ran {what}, not condition {s.entry.condition}'s")
    return "  (" + "; ".join(notes) + ")" if notes else ""


def _describe(study: Study, s: Standing) -> str:
    e = s.entry
    trials = ",".join(map(str, study.conditions.consensus))
    policy = study.policy_arg(e)
    cond = "" if policy is None else f"; condition {e.condition} (--policy {policy})"
    return (f"{e.id} (slot {e.slot} of {len(study.participants)}): O of trials {trials} = "
            f"{' '.join(e.order)}; the gaze looks toward O{cond}")


def _counts(r: Roster) -> str:
    return ", ".join(f"{n} {k}" for k, n in r.counts().items() if n or k != "withdrawn")


def _not_in(study: Study, participant: str) -> str:
    ids = [e.id for e in study.participants]
    span = f"{ids[0]}…{ids[-1]}" if len(ids) > 1 else ids[0]
    return f"{participant!r} is not in study {study.name} (its ids: {span})"


def _letters(study: Study) -> str:
    return letters(study.counterbalance.base, study.options)


def _when(t_ns: int) -> str:
    return datetime.fromtimestamp(t_ns / 1e9).isoformat(timespec="seconds")
