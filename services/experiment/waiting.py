"""Before a session: wait until every service the protocol needs is alive on the rig.

A conductor started on a wrong `--rig` sees nothing of its rig at all: after a few seconds it
says which rigs the router does have, and its timeout names them too.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence

from services.core.node import Node

log = logging.getLogger("nod.experiment")
HINT_AFTER_S = 3.0  # nothing of this rig alive for this long: list the rigs that are there


def wait_for_services(
    node: Node, alive: Mapping[str, bool], required: Sequence[str], timeout_s: float
) -> None:
    """Block until every `required` service's liveliness is in `alive` (fed by the node)."""
    start = time.monotonic()
    deadline, hinted = start + timeout_s, False
    while not all(alive.get(s) for s in required):
        others = ""
        now = time.monotonic()
        if not any(alive.values()) and (now - start > HINT_AFTER_S or now > deadline):
            others = node.other_rigs()  # a wrong --rig is the likely cause: say what is there
            if others and not hinted:
                hinted = True
                log.warning("nothing of rig %r is alive; on this router: %s (--rig?)",
                            node.keys.rig, others)
        if now > deadline or node.stop.is_set():
            missing = [s for s in required if not alive.get(s)]
            seen = f"; on this router: {others} (--rig?)" if others else ""
            raise TimeoutError(f"services not alive after {timeout_s:.0f} s: {missing}{seen}")
        time.sleep(0.02)


def hear_the_devices(node: Node, heard: Callable[[], bool], timeout_s: float) -> bool:
    """Block until `heard()` (locked: a state of each device arrived) or `timeout_s` (wall).

    Call it before `node.ready()`. A device in a safe stop because no conductor was alive
    clears it as soon as it sees this conductor's liveliness token; a state carrying that
    reason must reach the conductor first, or the stop during the gap is never stored (seen
    under load: the token and the subscription reached the arm in one batch). Devices not up
    yet are waited for later, by `wait_for_services`.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not node.stop.is_set():
        with node.lock:
            if heard():
                return True
        time.sleep(0.01)
    return False
