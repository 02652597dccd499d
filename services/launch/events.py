"""The launchers' account of their services: one console line and a RigEvent on rig/event.

`nod run` and `nod up` report every supervisor event through `RigEvents`: the experiment's
store and the monitor record them, `nod status` shows them.
"""

from __future__ import annotations

import logging
import socket
import sys
import threading

import zenoh

from services.core import messages as m
from services.core.clock import Clock
from services.core.contract import check_publisher
from services.core.keys import Keys
from services.core.node import clip, declare_publisher

log = logging.getLogger("nod.launch")


class RigEvents:
    """The launcher's events: one line on the console and a RigEvent on the fabric."""

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        clock: Clock | None = None,
        host: str | None = None,
    ) -> None:
        spec = check_publisher("rig/event", "launcher")
        self.clock = clock or Clock()  # the session's clock: events line up with the trials
        self._pub = declare_publisher(session, keys.topic("rig/event"), spec.qos)
        self.host = host or socket.gethostname()
        self.seq = 0
        self.lock = threading.Lock()
        self.quiet_starts = True  # the first start of each service is not news

    def __call__(
        self, service: str, kind: m.RigEventKind, code: int | None, restarts: int, text: str
    ) -> None:
        """Report one supervisor event."""
        with self.lock:
            msg = m.RigEvent(
                seq=self.seq, t_ns=self.clock.now_ns(), host=self.host[:200], service=service,
                kind=kind, code=None if code is None else max(-255, min(255, code)),
                restarts=restarts, text=clip(text, 400),
            )
            self.seq += 1
            try:
                self._pub.put(m.encode(msg))
            except Exception as exc:  # the console line below still tells the operator
                log.debug("rig event not published: %s", exc)
        if kind == "started" and restarts == 0 and self.quiet_starts:
            return
        if kind in ("exited", "stopped") and code == 0:
            return
        clear = "\r\033[K" if sys.stderr.isatty() else ""  # over the progress line
        print(f"{clear}[{service}] {kind}: {text}", file=sys.stderr, flush=True)
