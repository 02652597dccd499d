"""Connect a Watchdog to the fabric: the e-stop key and the needed services' liveliness.

Actuation and eyes both gate their outputs this way; this is the one place that wiring lives.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from services.core import messages as m
from services.core.node import Node
from services.model.safety import Watchdog

log = logging.getLogger("nod.safety")


def watch_safety_inputs(
    node: Node,
    watchdog: Watchdog,
    act_now: Callable[[int], None],
    also_watch: tuple[str, ...] = (),
) -> None:
    """Feed `watchdog` with e-stops and liveliness changes; call `act_now(now_ns)` on an e-stop.

    Liveliness is watched for every service in the watchdog's `require_alive` and in
    `also_watch` (services it requires only at times, e.g. the conductor during a trial); an
    e-stop (or its release) is acted on at once rather than at the next periodic tick.
    """

    def on_command(msg: m.Estop, engage: bool) -> None:
        if msg.engaged != engage:  # each key carries one direction (an ACL may guard release)
            raise ValueError(f"an e-stop {'release' if engage else 'engage'} on the wrong key")
        if watchdog.estopped == engage and watchdog.estop_id == msg.id:
            return  # a repeat of the command just obeyed
        watchdog.estop(engage, msg.reason or msg.source, msg.id)
        state = "ENGAGED" if engage else "released"
        log.warning("%s: e-stop %s by %s: %s", node.service, state, msg.source or "?", msg.reason)
        act_now(node.clock.now_ns())

    node.subscribe("safety/estop", lambda msg: on_command(msg, True))
    node.subscribe("safety/release", lambda msg: on_command(msg, False))
    for service in dict.fromkeys((*watchdog.params.require_alive, *also_watch)):
        node.watch_liveliness(service, lambda alive, s=service: watchdog.set_alive(s, alive))
