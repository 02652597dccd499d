"""`nod experiment --options N`: run one participant's N_o-option session and store it.

The command line's part for a table of three or more boxes: the same store, participant ids,
clicks, rig checks and resume as the paper's session (`services.experiment.resume` prepares a
resume for both), with `OptionsConductor`. The paper's session flags this conductor does not
do yet (`--order`, `--record`, `--again`) are refused with one line rather than ignored.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import uuid
from collections.abc import Callable

from services.core.cli import fail
from services.core.config import params_hash
from services.core.node import Node
from services.core.session import Fabric
from services.experiment.options_conductor import OptionsConductor
from services.experiment.resume import (
    prepare_resume,
    resume_problem,
    say_how_to_resume,
    warn_of_interrupted,
)
from services.experiment.rig_claim import claim_the_rig, watch_rivals
from services.model.params import NodConfig
from services.model.schedule import OptionsSchedule
from services.store import Store, back_up
from services.store.participants import next_free_ids

log = logging.getLogger("nod.experiment")
UNSUPPORTED = ("order", "record", "again")


def run_options(
    args: argparse.Namespace, cfg: NodConfig, schedule: OptionsSchedule,
    clicks: Callable[[int], int | None], store: Store, parser: argparse.ArgumentParser,
) -> int:
    """Run (or resume) the session of `schedule`; 0 when every trial is stored.

    `parser`: `nod experiment`'s, for the `resume with: …` line a stopped session leaves.
    """
    given = [f"--{name}" for name in UNSUPPORTED if getattr(args, name, None) is not None]
    if given:
        print(f"nod experiment: {', '.join(given)} not yet with --options "
              f"{schedule.n_options} (the paper's two-option session has them)", file=sys.stderr)
        return 2
    participant, seed, first = args.participant, args.seed, 1
    lost: tuple[int, int, int] | None = None
    resume_at: tuple[int, int] | None = None
    if args.resume is not None:  # refused before anything is written, as the paper's session
        if problem := resume_problem(store, args.resume, args.rig, schedule.names):
            return fail("nod experiment", problem)
        try:
            point = prepare_resume(store, args.resume, len(schedule.trials))
        except OSError as exc:
            return fail("nod experiment", exc)
        if point is None:  # every trial stored: marked complete, nothing to do
            return 0
        participant, seed, first = point.participant, point.seed, point.first
        lost, resume_at = point.lost, point.resume_at
    participant = participant or next_free_ids(store, 1)[0]
    warn_of_interrupted(store, args.resume)
    try:
        node = Node("experiment", Fabric.from_args(args), retry_s=math.inf,
                    params_hash=params_hash(cfg))
    except (ValueError, OSError, ConnectionError) as exc:
        print(f"nod experiment: {exc}", file=sys.stderr)
        return 2
    claim = claim_the_rig(node)
    if claim is None:
        node.close()
        return 2
    conductor = OptionsConductor(
        node, cfg, schedule, cfg.table(schedule.n_options), store, clicks,
        resume_at=resume_at,
    )
    watch_rivals(claim, node, conductor.rig, lambda text: log.warning("%s", text))
    node.ready()
    session = args.resume or args.session or uuid.uuid4().hex[:12]
    complete = False
    try:
        conductor.wait_for_services(args.wait_services)
        log.info("session %s (%s): %d options %s, trials %d-%d", session, participant,
                 schedule.n_options, list(schedule.names), first, len(schedule.trials))
        conductor.run_session(
            session, participant, seed, first, resume=args.resume is not None, lost=lost
        )
        complete = True
    except TimeoutError as exc:
        print(f"nod experiment: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        log.warning("session %s interrupted", session)
        # A stop mid-trial is on record as the operator's, not as a lost conductor.
        conductor.stop_mid_trial("the conductor was stopped (Ctrl-C or SIGTERM) mid-trial")
        return 130
    finally:
        node.close()
        back_up(store)  # the session ended (complete, stopped or aborted): a copy of the store
        if not complete:  # interrupted, aborted, or never started: how to go on with it
            say_how_to_resume(store, parser, args, session)
    log.info("session %s complete", session)
    return 0
