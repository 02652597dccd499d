"""The devices' share of the CPU: a device that must stop in 250 ms runs ahead of the rest.

Actuation and eyes act on an e-stop and on stale input; on a host also running the camera,
the decision model or anything else busy, the kernel's fair share can leave them waiting
(an e-stop took 1.27 s to stop the arm with two CPU burners on a 2-core host). Each device
asks for a higher priority (a lower nice value) when it starts; the systemd units grant it
(`Nice=` in the drop-in `deploy/setup-host` installs), and a process without the right
(CAP_SYS_NICE) says so in one line and runs at its normal priority.
"""

from __future__ import annotations

import logging
import os

log = logging.getLogger("nod.priority")
DEVICE_NICE = -10  # CFS weight 9548 against 1024 at nice 0: ~9 of 10 contended slices


def raise_priority(service: str, nice: int = DEVICE_NICE) -> bool:
    """Lower this process's nice value to `nice` if it is higher; whether it now runs at `nice`.

    Never lowers a priority already above it (a unit may grant more than this asks).
    """
    try:
        now = os.getpriority(os.PRIO_PROCESS, 0)
        if now <= nice:
            return True
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    except (PermissionError, OSError) as exc:
        log.info("%s: runs at its normal priority (nice %d wanted: %s; the systemd unit grants "
                 "it)", service, nice, exc.strerror or exc)
        return False
    log.debug("%s: nice %d (ahead of the rig's other work, for its safety bounds)", service, nice)
    return True
