"""Whether the rig lets the session go on, said once when it holds and once when it goes on.

Both conductors (the paper's and the N-option one) ask before each trial; the operator reads
one line when the session is held (with why) and one when the rig is safe again, not a line
per poll.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from services.experiment.rig_watch import RigWatch

log = logging.getLogger("nod.experiment")


@dataclass
class SessionHold:
    """The session's hold on an unsafe rig (see the module doc)."""

    rig: RigWatch
    note: Callable[[str], None] = lambda _text: None  # the console's line, if any
    held: bool = False
    said_estop: bool = False  # the hold's line named an engaged e-stop

    def ready(self, now_ns: int, quiet: bool = False, down: Sequence[str] = ()) -> bool:
        """Whether the rig is safe (and settled): said once when it holds, once when it goes on.

        `quiet`: a hold is expected now (the session's start); only an e-stop is said at once.
        `down`: services the session needs that are not running (their liveliness is gone): no
        trial starts without them. A decision service killed mid-trial is restarted within a
        second or two, but the devices look safe again sooner (the arm's watchdog waits for
        its stale bound); a trial repeated before it is back ran without it and timed out.
        """
        if down:
            if not self.held and not quiet:
                why = f"{', '.join(down)} not running (restarting?)"
                log.warning("session held: %s", why)
                self.note(f"session held: {why}")
                self.held = True
            return False
        if self.rig.safe(now_ns):
            if self.held:
                log.info("rig safe again: the session goes on")
                self.note("rig safe again: the session goes on")
                self.held = self.said_estop = False
            return True
        estop = self.rig.estop_engaged
        self.said_estop = self.said_estop and estop  # a released e-stop is said again if re-engaged
        # Said again when an e-stop is found engaged during a hold begun for another reason (a
        # restarted conductor may hear of the latched e-stop after a device's silence): the
        # operator must read what holds the session. Other changes of reason are not repeated.
        if (not self.held and not (quiet and not estop)) or (estop and not self.said_estop):
            log.warning("session held: %s", self.rig.why_unsafe())
            self.held, self.said_estop = True, estop
        return False
