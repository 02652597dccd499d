"""The line a stopped session leaves for the operator: the command that goes on with it.

`nod experiment` prints it when a session it ran (or resumed) ends before its last trial —
Ctrl-C, SIGTERM, an abort, services that never came up — and the session is in the store:
`resume with: nod experiment --resume SESSION --db DB …`, with the flags that reach the same
rig and store (session, clock, parameters, rig file, clicks, console, recording). `nod run`
prints its own form (`services.run`).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from services.store import Store

# The flags a resumed conductor needs as they were (argparse dests): how it reaches the rig and
# its clock, the parameters its trials ran with, and how the operator works. Not the new-session
# ones (--participant, --seed, --session, --order, --again): a session keeps its own.
RESUME_FLAGS = (
    "mode", "connect", "listen", "config", "rig", "rig_file", "speed", "epoch_ns", "params",
    "clicks", "console", "record", "wait_services",
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


def resume_problem(store: Store, session: str, rig: str) -> str | None:
    """Why `--resume session` may not go on in `store` on `rig` (one line), or None.

    Refused before anything is written: a session that is not there; one of another rig (its
    trials would be run on this rig's devices and stored under that one's name); a complete one
    (resuming it would reopen it and rewrite its finish time).
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
    return None


def say_how_to_resume(store: Store, parser: argparse.ArgumentParser,
                      args: argparse.Namespace, session: str) -> None:
    """Print the resume line on stderr if the session is stored and unfinished."""
    if stored_unfinished(store, session):
        print(resume_line(resume_argv(parser, args, session)), file=sys.stderr, flush=True)
