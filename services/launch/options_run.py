"""`nod run --sim --options N`: what a run of a table of N boxes does differently.

Every service that reads the table (decision, actuation, the sim, vision with `--render`,
the conductor) gets `--options N`; the eyes need no flag (the conductor sends them a gaze
toward a box, as ever). The flags of the paper's run that the N_o-option services do not do
yet are refused with one line before anything starts.
"""

from __future__ import annotations

import argparse
from typing import Any

from services.model.schedule import OptionsSchedule

TABLE_READERS = ("decision", "actuation", "sim", "vision", "experiment")
NOT_YET = ("order", "again", "record")


def with_options(sections: dict[str, dict[str, Any]], n_options: int) -> None:
    """Give every reader of the table `--options N` (in its rig section's `args`)."""
    for service in TABLE_READERS:
        sec = sections.setdefault(service, {})
        sec["args"] = [*sec.get("args", []), "--options", str(n_options)]


def options_problem(args: argparse.Namespace, schedule: OptionsSchedule) -> str | None:
    """Why this run cannot go with N options (one line), or None."""
    given = [f"--{f}" for f in NOT_YET if getattr(args, f, None) is not None]
    given += ["--rigs"] if args.rigs > 1 else []
    given += ["--arm-driver"] if args.arm_driver != "sim" else []
    if not given:
        return None
    return (f"{', '.join(given)}: not yet with {schedule.n_options} options "
            "(docs/multi-option.md); the paper's two-option run has them")
