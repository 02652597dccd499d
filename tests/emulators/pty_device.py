"""A serial device emulated on a real pseudo-terminal, with a plug you can pull.

The driver under test opens `port`: a symlink (like `/dev/serial/by-id/...`) to the slave side of
an `os.openpty()` pair; the emulator's thread reads and writes the master side and hands every
received chunk to `feed()`. `unplug()` closes the pty and removes the symlink, exactly what a
driver sees when a USB cable is pulled (reads and writes fail with EIO, reopening fails with
ENOENT); `replug()` makes a fresh pty behind the same path.
"""

from __future__ import annotations

import contextlib
import os
import select
import tempfile
import threading
import tty
from collections.abc import Callable
from pathlib import Path

from services.model.device import Scoped
from tests.polling import eventually


class PtyDevice(Scoped):
    """Base class: a byte-level device on a pty. Subclasses implement `feed`."""

    def __init__(self, link_dir: Path | None = None, name: str = "ttyEMU") -> None:
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        if link_dir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="nod-pty-")
            link_dir = Path(self._tmp.name)
        self.port = str(Path(link_dir) / name)
        self.received = bytearray()  # every byte the driver sent, for byte-exact asserts
        self.silent = False  # True: swallow requests and never answer
        self._lock = threading.Lock()
        self._master: int | None = None
        self._slave: int | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    # -- plug ----------------------------------------------------------------------------------
    def start(self) -> PtyDevice:
        """Create the pty, point `port` at it and start serving."""
        master, slave = os.openpty()
        tty.setraw(slave)  # the driver's pyserial sets raw mode too; this covers the gap
        self._master, self._slave = master, slave
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.port)
        os.symlink(os.ttyname(slave), self.port)
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name=type(self).__name__, daemon=True)
        self._thread.start()
        return self

    def unplug(self) -> None:
        """Pull the cable: stop serving, close both pty ends and remove the port path."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.port)

    def replug(self) -> None:
        """Plug the device back in: a new pty behind the same port path."""
        self.unplug()
        self.on_replug()
        self.start()

    def stop(self) -> None:
        """Unplug for good and remove the temporary directory."""
        self.unplug()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def _on_enter(self) -> None:
        self.start()

    def _on_exit(self) -> None:
        self.stop()

    # -- subclass hooks ------------------------------------------------------------------------
    def feed(self, data: bytes) -> None:
        """Consume bytes from the driver (called on the emulator thread)."""
        raise NotImplementedError

    def on_replug(self) -> None:
        """Reset the device state a power cycle would reset (default: nothing)."""

    # -- helpers for subclasses ----------------------------------------------------------------
    def send(self, data: bytes) -> None:
        """Write bytes toward the driver (dropped while `silent`)."""
        if self.silent or self._master is None:
            return
        with contextlib.suppress(OSError):
            os.write(self._master, data)

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float = 5.0) -> bool:
        """Poll `predicate` until true (write-only commands have no reply to wait for)."""

        def locked() -> bool:
            with self._lock:
                return predicate()

        return bool(eventually(locked, timeout_s, every_s=0.002))

    def take_received(self) -> bytes:
        """Return and clear the bytes received so far."""
        with self._lock:
            data = bytes(self.received)
            self.received.clear()
        return data

    def _serve(self) -> None:
        master = self._master
        assert master is not None
        # A real device answers in its own silicon, never starved by the host's load; the
        # emulator's thread shares a loaded test machine with everything else, and the drivers
        # (at nice -10 themselves, docs/safety.md) give up on a reply after 100 ms. So this
        # thread alone asks to be scheduled first, as far as the user may (Linux: a thread's
        # own nice value); without the right it serves at the normal priority.
        with contextlib.suppress(OSError, AttributeError):
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), -10)
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([master], [], [], 0.02)
            except (OSError, ValueError):
                return
            if not ready:
                continue
            try:
                data = os.read(master, 4096)
            except OSError:
                # EIO: the driver closed its end; wait for it to reopen.
                self._stop.wait(0.01)
                continue
            if not data:
                continue
            with self._lock:
                self.received.extend(data)
                self.feed(data)
