"""`nod experiment --options N`: run one participant's N_o-option session and store it.

The command line's part for a table of three or more boxes: the same store, participant ids,
clicks and rig checks as the paper's session, with `OptionsConductor`. The paper's session
flags this conductor does not do yet (`--resume`, `--order`, `--record`, `--again`) are
refused with one line rather than ignored.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import uuid
from collections.abc import Callable

from services.core.config import params_hash
from services.core.node import Node
from services.core.session import Fabric
from services.experiment.options_conductor import OptionsConductor
from services.experiment.rig_claim import claim_the_rig, watch_rivals
from services.model.options_loop import table_for
from services.model.params import NodConfig
from services.model.schedule import OptionsSchedule
from services.store import Store, back_up
from services.store.participants import next_free_ids

log = logging.getLogger("nod.experiment")
UNSUPPORTED = ("resume", "order", "record", "again")


def run_options(
    args: argparse.Namespace, cfg: NodConfig, schedule: OptionsSchedule,
    clicks: Callable[[int], int | None], store: Store,
) -> int:
    """Run the session of `schedule`; 0 when every trial is stored."""
    given = [f"--{name}" for name in UNSUPPORTED if getattr(args, name, None) is not None]
    if given:
        print(f"nod experiment: {', '.join(given)} not yet with --options "
              f"{schedule.n_options} (the paper's two-option session has them)", file=sys.stderr)
        return 2
    participant = args.participant or next_free_ids(store, 1)[0]
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
        node, cfg, schedule, table_for(cfg, schedule.n_options), store,
        clicks,
    )
    watch_rivals(claim, node, conductor.rig, lambda text: log.warning("%s", text))
    node.ready()
    session = args.session or uuid.uuid4().hex[:12]
    try:
        conductor.wait_for_services(args.wait_services)
        log.info("session %s (%s): %d options %s, %d trials", session, participant,
                 schedule.n_options, list(schedule.names), len(schedule.trials))
        conductor.run_session(session, participant, args.seed)
    except TimeoutError as exc:
        print(f"nod experiment: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        log.warning("session %s interrupted", session)
        return 130
    finally:
        node.close()
        back_up(store)  # the session ended (complete, stopped or aborted): a copy of the store
    log.info("session %s complete", session)
    return 0
