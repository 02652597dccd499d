"""One conductor per rig: the claim made before anything else, and the hold when another comes.

Two conductors on one rig would both run the protocol and store the same trials under
different participants. The claim (`services.core.claim`) is made as soon as the conductor's
session is open, before it hears the devices (up to 5 s, the window in which a second one used
to see nobody), so two started within a second of each other agree on one and the other says so
in one line and exits. A conductor that runs watches for claims that come later and holds its
session while one is there (a running trial is voided only if the other stays past its grace:
`RigWatch.rival`).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

from services.core.claim import Claim, RigTakenError
from services.core.node import Node
from services.experiment.rig_watch import RigWatch

CONDUCTOR_GONE_S = 2.0  # how long a conductor that just died may still look alive (wall)


def claim_the_rig(node: Node) -> Claim | None:
    """Claim the rig for this conductor; None (said why, one line) if another holds it.

    A conductor that already runs without a claim (an older `nod`, which holds only
    `alive/experiment`) is refused too.
    """
    claim = Claim(node.session, node.keys.rig, "experiment", label="conductor")
    try:
        claim.take(stop=node.stop)
        if _another_conductor(node):
            claim.release()
            raise RigTakenError(
                f"another conductor is running on rig {node.keys.rig!r} (its liveliness "
                f"{node.keys.alive('experiment')} is held): one rig, one conductor — stop it "
                "first, or use another --rig"
            )
    except RigTakenError as exc:
        print(f"nod experiment: {exc}", file=sys.stderr)
        return None
    return claim


def watch_rivals(claim: Claim, node: Node, rig: RigWatch, note: Callable[[str], None]) -> None:
    """From now on, another conductor's claim holds the session (`rig`) and is said."""

    def on_rival(other: str, present: bool) -> None:
        with node.lock:
            rig.rival(other, present, node.clock.now_ns())
        if present:
            note(f"another conductor claims this rig ({other}): the session holds")

    claim.on_rival = on_rival
    for other in sorted(claim.rivals):  # any that came while the conductor was being built
        on_rival(other, True)


def _another_conductor(node: Node) -> bool:
    """Whether another conductor holds this rig's `experiment` liveliness (past its grace)."""
    deadline = time.monotonic() + CONDUCTOR_GONE_S
    while node.peer_alive("experiment"):
        if time.monotonic() > deadline or node.stop.wait(0.1):
            return True
    return False
