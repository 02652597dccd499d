"""The e-stop latch on the device's own host: a small file, written before the device obeys.

Why a file on the device's host (and not only the fabric): the device is what must not move,
and its host is the one place that is there whenever the device is — a restarted service, a
rebooted controller, a router that is down all find it. The fabric adds what a file cannot:
a device whose file is new (a fresh install, another host) learns from its peers
(`safety/latch`, answered by every device) that the rig is stopped. See docs/safety.md.

The file is replaced atomically (write a temporary file, fsync, rename, fsync the folder), so
a crash leaves the old latch or the new one, never half of one. A file that cannot be read or
parsed counts as an engaged e-stop: the operator releases it explicitly.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

from services.model.latch import MAX_ORDER, MAX_SEEN, Latch, floor_of

STATE_DIR_ENV = "NOD_STATE_DIR"
PROBE_BYTES = 8192  # more than any latch file (64 ids of 64 characters and two texts of 200)


def default_state_dir() -> Path:
    """Where a device keeps its latch: $NOD_STATE_DIR, $XDG_STATE_HOME/nod or ~/.local/state/nod."""
    env = os.environ.get(STATE_DIR_ENV)
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_STATE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".local" / "state") / "nod"


def add_state_dir_arg(parser: argparse.ArgumentParser) -> None:
    """`--state-dir`: where a device keeps its e-stop latch (actuation, eyes)."""
    parser.add_argument(
        "--state-dir",
        type=Path,
        default=None,
        help=f"folder of the device's e-stop latch file (default ${STATE_DIR_ENV}, else "
        "$XDG_STATE_HOME/nod or ~/.local/state/nod); it survives restarts of the service",
    )


class LatchFile:
    """The latch of one device of one rig: `<state_dir>/estop-<rig>-<device>.json`."""

    def __init__(self, state_dir: Path, rig: str, device: str) -> None:
        self.path = Path(state_dir) / f"estop-{rig}-{device}.json"

    def check_writable(self) -> None:
        """Create the folder and prove a latch can be saved there (OSError with the path if not).

        The probe writes and syncs as many bytes as the largest latch: on a full disk an empty
        file can still be created (an inode is free), and an empty probe let a device start
        whose every e-stop would then fail to save.
        """
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.NamedTemporaryFile(dir=self.path.parent, prefix=".probe-") as fh:
                fh.write(b"\0" * PROBE_BYTES)
                fh.flush()
                os.fsync(fh.fileno())
        except OSError as exc:
            raise OSError(f"cannot keep the e-stop latch in {self.path.parent}: {exc}") from None

    def load(self) -> Latch:
        """The saved latch: released if there is none yet; engaged if it cannot be read."""
        try:
            raw = self.path.read_bytes()
        except FileNotFoundError:
            return Latch()
        except OSError as exc:
            return Latch(True, f"latch file unreadable ({exc.strerror or exc})", "", "")
        try:
            data = json.loads(raw)
            engaged = data["engaged"]
            reason, source, cid = data["reason"], data["source"], data["id"]
            seen = tuple(data["seen"])[-MAX_SEEN:]
            if not isinstance(engaged, bool) or not all(
                isinstance(v, str) for v in (reason, source, cid, *seen)
            ):
                raise TypeError("wrong field types")
            # A latch saved before floors existed: the highest order among what it remembers.
            floor = data.get("floor", floor_of((*seen, cid)))
            if isinstance(floor, bool) or not isinstance(floor, int) or not 0 <= floor <= MAX_ORDER:
                raise TypeError(f"floor {floor!r} is not an order")
        except (ValueError, KeyError, TypeError) as exc:
            return Latch(True, f"latch file {self.path.name} corrupt ({exc})", "", "")
        return Latch(engaged, reason, source, cid, seen, floor)

    def save(self, latch: Latch) -> None:
        """Replace the saved latch atomically and durably (OSError if it cannot)."""
        body = json.dumps({
            "engaged": latch.engaged, "reason": latch.reason, "source": latch.source,
            "id": latch.id, "seen": list(latch.seen), "floor": latch.floor,
        }).encode()
        folder = self.path.parent
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{self.path.name}.")
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(body)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        dir_fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(dir_fd)  # the rename itself survives a power cut
        finally:
            os.close(dir_fd)
