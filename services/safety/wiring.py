"""Connect a Watchdog to the fabric: the e-stop latch, the e-stop keys, the needed liveliness.

Actuation and eyes both gate their outputs this way; this is the one place that wiring lives.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from typing import Protocol

from services.core import messages as m
from services.core.node import Node
from services.model.latch import Latch
from services.model.safety import Watchdog
from services.safety.latch_file import LatchFile

log = logging.getLogger("nod.safety")
ASK_PEERS_S = 1.0  # how long a starting device waits for the other devices' latches (wall)


def watch_safety_inputs(
    node: Node,
    watchdog: Watchdog,
    act_now: Callable[[int], None],
    latch_file: LatchFile | None,
    also_watch: tuple[str, ...] = (),
) -> None:
    """Feed `watchdog` with the latch, e-stops and liveliness; `act_now(now_ns)` on an e-stop.

    The latch comes from `latch_file` (None: kept in memory only, for in-process tests) merged
    with what the rig's other devices answer on `safety/latch`; until both are in, the watchdog
    keeps the device stopped. The e-stop keys are heard on the node's safety path
    (`Node.subscribe_urgent`), never behind data. An engage is acted on at once, then saved to
    the file, and acknowledged only once saved; a release is saved before the device acts on it
    (moves again), and one that cannot be saved is not obeyed. A latch that cannot be saved
    keeps the device stopped (the state key says why) and is retried every second until it is.
    Liveliness is watched for every service in the watchdog's `require_alive` and in
    `also_watch` (services it requires only at times, e.g. the conductor during a trial); an
    e-stop (or its release) is acted on at once rather than at the next periodic tick.
    """
    with node.lock:
        if latch_file is not None:
            watchdog.latch = latch_file.load()
            if watchdog.latch.engaged:
                log.warning("%s: e-stop ENGAGED (latched in %s): %s", node.service,
                            latch_file.path, watchdog.latch.reason)

    def save() -> bool:
        """Save the latch (under the node's lock); whether it is on disk now."""
        if latch_file is not None:
            try:
                latch_file.save(watchdog.latch)
            except OSError as exc:
                why = f"{latch_file.path.parent}: {exc.strerror or exc}"
                if why != watchdog.latch_unsaved:  # one line per new cause, not per retry
                    log.error("%s: e-stop latch NOT saved (%s): stays stopped until it is",
                              node.service, why)
                watchdog.latch_not_saved(why)
                return False
        if watchdog.latch_unsaved:
            log.warning("%s: e-stop latch saved again", node.service)
        watchdog.latch_saved()
        return True

    def on_command(msg: m.Estop, engage: bool) -> None:
        if msg.engaged != engage:  # each key carries one direction (an ACL may guard release)
            raise ValueError(f"an e-stop {'release' if engage else 'engage'} on the wrong key")
        verdict = watchdog.command(engage, msg.reason or msg.source, msg.source, msg.id)
        if verdict == "repeat":
            if watchdog.latch_unsaved:
                save()  # `nod estop` repeats an unacknowledged command: try the disk again
                act_now(node.clock.now_ns())
            return  # `nod estop` repeats a command until every device has acknowledged it
        if verdict == "refused":
            raise ValueError(
                f"a release with a stale id ({msg.id!r}: issued before a command this device "
                "obeyed, replayed?) is refused"
            )
        if engage:  # stop at once: two fsyncs on a busy disk took over a second under load
            act_now(node.clock.now_ns())
        if not save() and not engage:
            watchdog.revert_command(f"{watchdog.latch_unsaved} (the release was not obeyed)")
            log.error("%s: e-stop release by %s NOT obeyed: its latch cannot be saved",
                      node.service, msg.source or "?")
            act_now(node.clock.now_ns())
            return
        state = "ENGAGED" if engage else "released"
        log.warning("%s: e-stop %s by %s: %s", node.service, state, msg.source or "?", msg.reason)
        act_now(node.clock.now_ns())  # and acknowledged (estop_id) once saved

    def retry_unsaved(now_ns: int) -> None:
        if watchdog.latch_unsaved:
            save()

    def latch_msg() -> m.LatchMsg:
        latch = watchdog.latch
        return m.LatchMsg(
            seq=0, t_ns=node.clock.now_ns(), service=node.service, engaged=latch.engaged,
            reason=latch.reason, source=latch.source, id=latch.id, seen=latch.seen,
            floor=latch.floor,
        )

    node.subscribe_urgent("safety/estop", lambda msg: on_command(msg, True))
    node.subscribe_urgent("safety/release", lambda msg: on_command(msg, False))
    node.every(1.0, retry_unsaved)
    node.answer("safety/latch", latch_msg)
    peers = [
        Latch(r.engaged, r.reason, r.source, r.id, r.seen, r.floor)
        for r in node.ask("safety/latch", ASK_PEERS_S)
        if r.service != node.service
    ]
    with node.lock:
        before = watchdog.latch
        watchdog.adopt(*peers)
        if watchdog.latch != before:
            save()
        if watchdog.latch.engaged and not before.engaged:
            log.warning("%s: e-stop ENGAGED (held by a peer device): %s", node.service,
                        watchdog.latch.reason)
        log.info("%s: e-stop state known (%s, %d peer(s) asked)", node.service,
                 "ENGAGED" if watchdog.latch.engaged else "released", len(peers))
    for service in dict.fromkeys((*watchdog.params.require_alive, *also_watch)):
        node.watch_liveliness(service, functools.partial(watchdog.set_alive, service))


class SafeDevice(Protocol):
    """A device a service drives: a safe state to go to, and a connection to close."""

    def make_safe(self) -> object:
        """Put the device in its safe state (the arm holds, the eyes look ahead)."""

    def disconnect(self) -> None:
        """Close the connection (idempotent)."""


def run_device_service(node: Node, device: SafeDevice) -> None:
    """Run a device's service until it is signalled to stop; the device left safe, then closed.

    However the service ends — a clean stop, an error, or a clean stop that hangs and is forced
    (`Node.on_forced_exit`) — the device is put in its safe state before anything else.
    """
    node.on_forced_exit(device.make_safe)
    try:
        node.run()
    finally:
        device.make_safe()
        device.disconnect()
