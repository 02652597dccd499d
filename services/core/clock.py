"""Clocks: wall time in the lab, a shared scaled clock under simulation.

Every process of a `nod run --sim` session gets the same `--epoch-ns` and `--speed`, so they all
read the same simulated time without exchanging clock messages:
    sim_ns = epoch_ns + speed · (wall_ns − epoch_ns)
At speed 1 this is the wall clock, which is what every message's `t_ns` carries on a real rig
(hosts synchronised by NTP/PTP), so staleness can be judged across hosts.
"""

from __future__ import annotations

import argparse
import threading
import time


class Clock:
    """A clock in ns; `speed` is simulated seconds per wall second."""

    def __init__(self, speed: float = 1.0, epoch_ns: int | None = None) -> None:
        if not speed > 0:
            raise ValueError(f"clock speed must be > 0, got {speed}")
        self.speed = float(speed)
        self.epoch_ns = time.time_ns() if epoch_ns is None else int(epoch_ns)

    def now_ns(self) -> int:
        """The current (simulated) time in ns."""
        wall = time.time_ns()
        if self.speed == 1.0:
            return wall
        return self.epoch_ns + int((wall - self.epoch_ns) * self.speed)

    def wall_seconds(self, sim_seconds: float) -> float:
        """How long `sim_seconds` of simulated time lasts on the wall clock."""
        return sim_seconds / self.speed

    def sleep(self, sim_seconds: float, stop: threading.Event | None = None) -> bool:
        """Sleep for simulated seconds; return True early if `stop` gets set."""
        wall = max(0.0, self.wall_seconds(sim_seconds))
        if stop is None:
            time.sleep(wall)
            return False
        return stop.wait(wall)


def add_clock_args(parser: argparse.ArgumentParser) -> None:
    """Add `--speed` and `--epoch-ns` (set by `nod run`; leave alone on a real rig)."""
    g = parser.add_argument_group("clock")
    g.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="simulated seconds per wall second (simulation only; default 1)",
    )
    g.add_argument(
        "--epoch-ns",
        type=int,
        default=None,
        help="wall time (ns) where the shared simulated clock starts (set by `nod run`)",
    )
