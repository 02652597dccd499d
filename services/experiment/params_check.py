"""The conductor runs the rig's parameters, or does not start: `nod experiment`'s params check.

Each service publishes a hash of its effective parameters in its heartbeat (`NodeStatus.
params_hash`, `services.core.config.params_hash`: of the values, not of the file). Before the
session, the conductor listens to rig/status until it has heard decision and actuation (at most
`HEARD_WAIT_S`) and refuses to run when either hash differs from its own: a conductor judging
trials by one protocol and bias while the decision service integrates another would store
sessions that look right and are not. A service not heard in time, or one that sends no hash
(an older version), is a warning, not a refusal: the check cannot tell.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from services.core import messages as m
from services.core.node import Node

log = logging.getLogger(__name__)
CHECKED = ("decision", "actuation")  # whose parameters decide a trial besides the conductor's
HEARD_WAIT_S = 3.0  # wall seconds to hear their heartbeats (1 Hz) once they are alive


class ParamsCheck:
    """The latest params hash each service sent on rig/status (subscribed at construction)."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.heard: dict[str, str | None] = {}
        node.subscribe("rig/status", self.on_status)

    def on_status(self, status: m.NodeStatus) -> None:
        """Keep a heartbeat's hash (runs under the node's lock)."""
        self.heard[status.service] = status.params_hash

    def problem(self, own: str, params: Path | None, wait_s: float = HEARD_WAIT_S) -> str | None:
        """One line saying which service runs other parameters, or None (checked or unknowable).

        `own` is the conductor's hash of `params` (None: SPEC defaults). Waits up to `wait_s` for
        a heartbeat of each of CHECKED.
        """
        deadline = time.monotonic() + wait_s
        while not all(s in self.heard for s in CHECKED):
            if time.monotonic() > deadline or self.node.stop.wait(0.05):
                break
        with self.node.lock:
            heard = dict(self.heard)
        for service in CHECKED:
            if service not in heard:
                log.warning("params check: no heartbeat from %s within %.0f s: its parameters "
                            "are not compared", service, wait_s)
            elif heard[service] is None:
                log.warning("params check: %s sends no params hash (an older version?): its "
                            "parameters are not compared", service)
        other = [(s, h) for s in CHECKED if (h := heard.get(s)) is not None and h != own]
        if not other:
            if all(heard.get(s) == own for s in CHECKED):
                log.info("params check: %s run this conductor's parameters (hash %s)",
                         " and ".join(CHECKED), own)
            return None
        theirs = " and ".join(f"{s} (params hash {h})" for s, h in other)
        ours = f"{params}" if params is not None else "SPEC defaults, no --params"
        verb = "runs" if len(other) == 1 else "run"
        return (
            f"{theirs} {verb} other parameters than this conductor (params hash {own}, from "
            f"{ours}): give them one params file (restart the service with this one, or start "
            "the conductor with the rig's: `--rig-file RIG.toml`); --allow-params-mismatch "
            "runs it anyway"
        )
