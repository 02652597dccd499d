"""Whether the rig lets the session go on, said once when it holds and once when it goes on.

Both conductors (the paper's and the N-option one) ask before each trial; the operator reads
one line when the session is held (with why) and one when the rig is safe again, not a line
per poll.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

from services.experiment.rig_watch import RigWatch

log = logging.getLogger("nod.experiment")


@dataclass
class SessionHold:
    """The session's hold on an unsafe rig (see the module doc)."""

    rig: RigWatch
    note: Callable[[str], None] = lambda _text: None  # the console's line, if any
    held: bool = False

    def ready(self, now_ns: int, quiet: bool = False) -> bool:
        """Whether the rig is safe (and settled): said once when it holds, once when it goes on.

        `quiet`: a hold is expected now (the session's start); only an e-stop is said at once.
        """
        if self.rig.safe(now_ns):
            if self.held:
                log.info("rig safe again: the session goes on")
                self.note("rig safe again: the session goes on")
                self.held = False
            return True
        if not self.held and not (quiet and not self.rig.estop_engaged):
            log.warning("session held: %s", self.rig.why_unsafe())
            self.held = True
        return False
