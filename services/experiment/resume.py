"""The line a stopped session leaves for the operator: the command that goes on with it.

`nod experiment` prints it when a session it ran (or resumed) ends before its last trial —
Ctrl-C, SIGTERM, an abort, services that never came up — and the session is in the store:
`resume with: nod experiment --resume SESSION --db DB …`, with the flags that reach the same
rig and store (session, clock, parameters, option count, rig file, clicks, console, recording).
`nod run` prints its own form (`services.run`).

And what a resume does before its conductor runs, in one place for the paper's conductor and
the N-option one (`prepare_resume`, `attempts_so_far`, `file_open_attempt`): written once, so
the two cannot drift apart on where a session goes on or on how a lost attempt is filed.
"""

from __future__ import annotations

import argparse
import logging
import shlex
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from services.model.protocol import ProtocolParams
from services.store import (
    CueRecord,
    Interruption,
    RigEventRecord,
    SafetyEvent,
    Store,
    back_up,
)

log = logging.getLogger("nod.experiment")
LOST = "conductor lost (it died mid-trial; the session was resumed)"
OUT_OF_ATTEMPTS = "interrupted: out of attempts before the session was resumed"

# The flags a resumed conductor needs as they were (argparse dests): how it reaches the rig and
# its clock, the parameters its trials ran with, and how the operator works. Not the new-session
# ones (--participant, --seed, --session, --order, --again): a session keeps its own.
RESUME_FLAGS = (
    "mode", "connect", "listen", "config", "rig", "rig_file", "speed", "epoch_ns", "params",
    "options", "clicks", "console", "record", "wait_services",
)


def resume_argv(
    parser: argparse.ArgumentParser,
    args: argparse.Namespace,
    session: str,
    prog: tuple[str, ...] = ("nod", "experiment"),
    flags: tuple[str, ...] = RESUME_FLAGS,
) -> list[str]:
    """The command line that resumes `session` with those of `args`' `flags` not at default."""
    return [*prog, "--resume", session, "--db", str(args.db), *flag_argv(parser, args, flags)]


def flag_argv(
    parser: argparse.ArgumentParser, args: argparse.Namespace, flags: tuple[str, ...]
) -> list[str]:
    """Those of `args`' `flags` that are not at their default, as command-line arguments."""
    argv: list[str] = []
    for dest in flags:
        value = getattr(args, dest, None)
        if value is None or value is False or value == parser.get_default(dest):
            continue
        flag = "--" + dest.replace("_", "-")
        if value is True:  # a switch
            argv.append(flag)
            continue
        for v in value if isinstance(value, list) else [value]:
            text = str(v)  # a value that looks like a flag (--monitor=--spawn) is joined to it
            argv += [f"{flag}={text}"] if text.startswith("-") else [flag, text]
    return argv


def resume_line(argv: list[str]) -> str:
    """`resume with: …`, quoted for a shell."""
    return "resume with: " + shlex.join(argv)


def stored_unfinished(db: Path | Store, session: str) -> bool:
    """Whether `session` is in the store and not complete (a resume has something to do)."""
    return session_status(db, session) not in (None, "complete")


def session_status(db: Path | Store, session: str) -> str | None:
    """A session's stored status (running, aborted, complete), or None if it is not stored."""
    if isinstance(db, Store):
        return next((str(s["status"]) for s in db.sessions() if s["session"] == session), None)
    if not Path(db).is_file():
        return None
    with Store(db) as store:
        return session_status(store, session)


def resume_problem(
    store: Store, session: str, rig: str, options: Sequence[str] | None = None
) -> str | None:
    """Why `--resume session` may not go on in `store` on `rig` (one line), or None.

    Refused before anything is written: a session that is not there; one of another rig (its
    trials would be run on this rig's devices and stored under that one's name); a complete one
    (resuming it would reopen it and rewrite its finish time); one of another option set than
    `options`, the one this conductor's parameters give (its next trials would be run on
    another table, and the store refuses their boxes' names only once a trial has been run).
    """
    known = {s["session"]: s for s in store.sessions()}
    stored = known.get(session)
    if stored is None:
        return f"--resume: no session {session!r} in {store.path}; known: " + (
            ", ".join(list(known)[-5:]) or "none"
        )
    if stored["rig"] != rig:
        return (
            f"--resume: session {session} ran on rig {stored['rig']!r}, this is rig {rig!r}: "
            f"resume it on its own rig (--rig {stored['rig']}); nothing was changed"
        )
    if stored["status"] == "complete":
        (trials,) = store.db.execute(
            "SELECT COUNT(*) FROM trials WHERE session = ?", (session,)
        ).fetchone()
        return (
            f"--resume: session {session} of {stored['participant']} is complete ({trials} "
            "trial(s) stored): nothing to resume, and it is left as it is; another session "
            "of that participant is started with --again REASON"
        )
    stored_options = store.option_names(session)
    if options is not None and tuple(options) != stored_options:
        return (
            f"--resume: session {session} ran the options {list(stored_options)}, these "
            f"parameters give {list(options)}: resume it with its own (--options "
            f"{len(stored_options)} or its params file); nothing was changed"
        )
    return None


@dataclass(frozen=True)
class ResumePoint:
    """Where a stored session goes on: what its conductor needs to resume it."""

    session: str
    participant: str  # the session's own, whatever the command line says
    seed: int | None
    done: int  # trials stored
    lost: tuple[int, int, int] | None  # (trial, attempt, t_start_ns) a dead conductor left open
    # The (trial, attempt) the session stands in: the safety events heard before its next trial
    # starts (a device's safe stop while no conductor ran) are filed under it, not trial 0.
    resume_at: tuple[int, int]

    @property
    def first(self) -> int:
        """The first trial to run (the one after the last stored)."""
        return self.done + 1


def prepare_resume(
    store: Store, session: str, n_trials: int, prog: str = "nod experiment"
) -> ResumePoint | None:
    """Mark `session` running again and say where it stands; None if nothing is left to run.

    Call it once `resume_problem` found nothing (OSError if the store cannot). A session with
    all `n_trials` stored and no attempt open (its conductor died after its last trial, before
    its end was stored) is marked complete and backed up here, with one line on stdout.
    """
    participant, seed, done = store.resume_session(session)
    lost = store.open_attempt(session)
    broken = store.attempts_made(session, done + 1)
    # In the attempt a dead conductor left open, paused after an interrupted start of its next
    # trial, or between trials (after trial `done`).
    resume_at = (
        (lost[0], lost[1]) if lost is not None else (done + 1, broken) if broken else (done, 1)
    )
    if done >= n_trials and lost is None:
        store.finish_session(session, time.time_ns(), "complete")
        back_up(store)
        print(f"{prog}: session {session} has all {done} trials; nothing to do")
        return None
    return ResumePoint(session, participant, seed, done, lost, resume_at)


def warn_of_interrupted(store: Store, resumed: str | None) -> None:
    """Log every other session a crash left running, with the command that goes on with it."""
    for session, done in store.interrupted_sessions():
        if session != resumed:
            log.warning(
                "session %s was interrupted after %d stored trial(s): go on with it with "
                "`nod experiment --resume %s`",
                session,
                done,
                session,
            )


def attempts_so_far(
    store: Store,
    session: str,
    proto: ProtocolParams,
    first_trial: int,
    lost: tuple[int, int, int] | None,
    file_lost: Callable[[tuple[int, int, int], str], None],
    give_up: Callable[[int, int, str], object],
) -> tuple[int, int]:
    """(first trial to run, its starts so far) for a session that starts or resumes.

    A resumed session counts the starts its trial already had: interruptions stored before
    the crash, and the attempt a dead conductor left open (`lost`), which `file_lost` stores
    now as the interruption it was. Like any interruption, the trial is then repeated while it
    has attempts left, else `give_up(trial, attempts, reason)` stores it interrupted (never
    scored) and the session goes on. The conductors differ only in how they store.
    """
    n = len(proto.trials)
    while first_trial <= n:
        made = store.attempts_made(session, first_trial)
        if lost is not None and lost[0] == first_trial:
            file_lost(lost, LOST)
            made = max(made, lost[1])
        if made == 0 or (proto.repeat_interrupted and made < proto.max_attempts):
            return first_trial, made
        give_up(first_trial, made, OUT_OF_ATTEMPTS)  # out of attempts: never scored
        first_trial += 1
    return first_trial, 0


def file_open_attempt(
    store: Store,
    session: str,
    lost: tuple[int, int, int],
    why: str,
    end_ns: int,
    events: Iterable[SafetyEvent | RigEventRecord] = (),
    cues: Iterable[CueRecord] = (),
) -> None:
    """Store an attempt left open, (trial, attempt, t_start_ns), as an interruption."""
    trial, attempt, t_start_ns = lost
    log.warning("trial %d (attempt %d) INTERRUPTED: %s", trial, attempt, why)
    store.write_interruption(
        session, Interruption(trial, attempt, t_start_ns, end_ns, why), events, cues
    )


def say_how_to_resume(store: Store, parser: argparse.ArgumentParser,
                      args: argparse.Namespace, session: str) -> None:
    """Print the resume line on stderr if the session is stored and unfinished."""
    if stored_unfinished(store, session):
        print(resume_line(resume_argv(parser, args, session)), file=sys.stderr, flush=True)
