"""The `nod` command: one entry point that dispatches to each service's or tool's own `main`.

Each subcommand lives in its own module with a `main(argv) -> int`, so `nod decision …` and
`python -m services.decision …` run the same code, and importing the CLI stays cheap (a
subcommand's heavy imports happen only when it runs).
"""

from __future__ import annotations

import contextlib
import importlib
import os
import sys

from services.core.cli import one_line
from services.core.lifeline import die_with_parent

COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("services.run", "start a router and every service; run a session"),
    "up": ("services.launch.up", "start a rig's services from its rig file, supervised"),
    "status": ("services.tools.status", "every service of a rig: alive, restarts, rates, clocks"),
    "router": ("services.core.router", "a zenoh router for the lab's control station"),
    "decision": ("services.decision.service", "opinion dynamics service (eqs 1, 6, 7)"),
    "actuation": ("services.actuation.service", "robot arm behaviour service (Algorithm 2)"),
    "eyes": ("services.eyes.service", "gaze / servo eyes service (Section 5)"),
    "sim": ("services.sim.service", "synthetic participant publishing hand poses"),
    "speaker": ("services.speaker.service", "the participant's audio countdown and go tone"),
    "display": ("services.display.service", "the participant's screen: a web page for a kiosk"),
    "lsl": ("services.lsl.service", "the rig's signals and trial markers as LSL outlets"),
    "cohort": ("services.sim.cohort", "a simulated cohort, offline on every core, as a study"),
    "calibrate-cohort": ("services.sim.calibrate", "fit the sim participant to outcome shares"),
    "vision": ("services.vision.service", "camera capture and hand tracking"),
    "experiment": ("services.experiment.service", "conductor of the 8-trial protocol"),
    "estop": ("services.safety.estop", "publish (or release) an emergency stop"),
    "report": ("services.experiment.report", "per-trial results from a session database"),
    "analyze": ("services.analysis.cli", "numerical analysis and statistics"),
    "fit": ("services.fit.cli", "each participant's model parameters; a recovery study"),
    "estimate": ("services.fit.live", "the participant's parameters after each trial, live"),
    "questionnaire": ("services.experiment.questionnaire", "enter or import Q1-Q5 answers"),
    "clicks": ("services.experiment.clicks", "enter or correct a stored trial's counter clicks"),
    "export": ("services.experiment.export", "write a session database as CSV"),
    "store": ("services.store.cli", "the session store: `nod store check --db FILE` (integrity)"),
    "study": ("services.study.cli", "a study's roster: orders, consent, who is next, start"),
    "monitor": ("services.monitor.service", "live view of every key in Rerun"),
    "topic": ("services.tools.topic", "list, echo and measure the rig's keys"),
    "record": ("services.recording.record", "record every key of a rig into an MCAP file"),
    "replay": ("services.recording.replay", "replay a recording, or re-run decision on it"),
    "ports": ("services.tools.ports", "serial devices with their USB ids"),
    "lab": ("services.lab.cli", "lab tools: `nod lab secure` (mutual TLS, ACL), `nod lab status`"),
}


# Tools that read as a service's verbs: `nod experiment next` is the operator's, not the
# conductor's (it runs on any host, while the conductor runs the session).
VERBS: dict[tuple[str, str], str] = {
    ("experiment", "next"): "services.tools.operator",
    ("experiment", "pause"): "services.tools.operator",
    ("experiment", "freeze"): "services.tools.operator",
}


def _usage() -> str:
    lines = ["usage: nod <command> [options]", "", "commands:"]
    lines += [f"  {name:<11} {help_}" for name, (_, help_) in COMMANDS.items()]
    lines += ["", "Run `nod <command> --help` for the options of one command."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Dispatch `nod <command> …` to the command's module."""
    die_with_parent()  # under a launcher: end with it, even if it is SIGKILLed
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in {"-h", "--help", "help"}:
        print(_usage())
        return 0
    name, rest = args[0], args[1:]
    if name not in COMMANDS:
        print(f"nod: unknown command {name!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    verb = VERBS.get((name, rest[0])) if rest else None
    if verb is not None:
        name, module = f"{name} {rest[0]}", importlib.import_module(verb)
    else:
        module = importlib.import_module(COMMANDS[name][0])
    try:
        return int(module.main(rest) or 0)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # The reader went away (`nod … | head`): not an error of ours. Point stdout at devnull
        # so the interpreter's final flush does not complain either.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except Exception as exc:  # the last line of defence: one line, not a traceback
        if os.environ.get("NOD_TRACEBACK"):
            raise
        text = one_line(str(exc))
        hint = "(NOD_TRACEBACK=1 shows where)"
        print(f"nod {name}: {type(exc).__name__}: {text} {hint}", file=sys.stderr)
        return 1


# The long-running services of a rig: each holds a Zenoh session whose native threads deliver
# callbacks. Ending such a process through the interpreter's finalisation races them: a callback
# thread that asks for the GIL while Python finalises is ended by pthread_exit inside Rust code,
# which aborts the process ("FATAL: exception not rethrown", SIGABRT) after a clean run — a
# conductor that had stored its whole session was seen "crashing" so, and restarted by its
# supervisor. Every service has closed its session, store and devices in its own `finally` by the
# time its `main` returns, and none registers atexit work, so they end there, at once.
ENDS_AT_ONCE = frozenset({"decision", "actuation", "eyes", "sim", "speaker", "display", "lsl",
                          "vision", "experiment", "router", "estimate"})


def entry() -> int:
    """The `nod` executable: `main`, then a service's process ends without finalisation."""
    argv = sys.argv[1:]
    code = main(argv)
    if argv and argv[0] in ENDS_AT_ONCE and (argv[0], *argv[1:2]) not in VERBS:
        import logging

        logging.shutdown()
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError):  # a gone reader: nothing left to say
                stream.flush()
        os._exit(code)
    return code


if __name__ == "__main__":
    raise SystemExit(entry())
