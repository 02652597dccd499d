"""What every servo driver on a serial port shares: latched targets, reconnect and a fault string.

A serial servo driver never raises on a link failure once connected, and never blocks its
caller: `send()` enforces the calibration's limits, latches the targets and returns at once;
the serial I/O runs on the driver's own thread, which writes the latched targets, probes the
controller a few times a second, reopens a vanished port with backoff and initialises the
controller again after a reopen (an Arduino's boot wait of seconds included) — so the service's
tick, its safety gate and its state key keep their pace whatever the device does. The thread
works when woken: by `send()` and by `poll()` (the service calls it every tick, so a silent
controller is noticed within a tick or two). `fault` says what is wrong; the targets stay
latched, so the eyes end where they were last told to look.
"""

from __future__ import annotations

import logging
import threading
import time
from abc import abstractmethod
from typing import Generic, Protocol, TypeVar

from services.core.serial_link import LinkConfig, LinkedDevice, LinkError, SerialLink
from services.eyes.servos import ServoDriver, ServoNotConnectedError
from services.model.servos import EyesCalibration, ServoTargets, enforce_limits

log = logging.getLogger(__name__)
FLUSH_S = 0.5  # how long disconnect() waits for the last targets to go out


class PortConfig(Protocol):
    """What a controller's configuration gives its driver to open the port with."""

    @property
    def baudrate(self) -> int:
        """The port's baud rate."""

    @property
    def link(self) -> LinkConfig:
        """The link's timeouts and reconnect backoff."""


ConfigT = TypeVar("ConfigT", bound=PortConfig)


class SerialServoDriver(LinkedDevice, ServoDriver, Generic[ConfigT]):
    """Base of the Maestro and Arduino drivers; subclasses speak the protocol.

    A subclass names its configuration type and its defaults (`default_config`); the port, the
    link and the calibration are taken here, the same way for every controller.
    """

    #: Human name of the controller, for messages.
    device = "servo controller"
    #: How to fix a controller that does not answer at connect time.
    hint = "check the cable, the --port path and the baud rate"

    def __init__(
        self,
        port: str,
        config: ConfigT | None = None,
        calibration: EyesCalibration | None = None,
        *,
        link: SerialLink | None = None,
    ) -> None:
        """Drive the eyes through the controller on `port` (opened by `connect()`).

        `link` replaces the link to `port` the configuration describes (tests pass their own).
        """
        super().__init__(calibration)
        self.config: ConfigT = config if config is not None else self.default_config()
        if link is None:
            link = SerialLink(port, self.config.baudrate, self.config.link)
        self.link = link
        self._connected = False
        self._generation = -1  # link.opens at the last initialisation of the controller
        self._latched: ServoTargets | None = None
        self._pending = False  # latched targets not yet confirmed written
        self._fault: str | None = None
        self._state = threading.Lock()  # guards the three fields above, never held during I/O
        self._wake = threading.Event()
        self._quit = threading.Event()
        self._worker: threading.Thread | None = None
        self._cycles = 0  # completed I/O cycles (tests and flushes wait on it)
        self._busy = False  # inside an I/O cycle
        self._cycled = threading.Condition()

    # -- interface -----------------------------------------------------------------------------
    @property
    def latched(self) -> ServoTargets | None:
        """The targets the driver holds the servos at (re-sent after a reconnect)."""
        return self._latched

    def connect(self) -> None:
        """Open the port and initialise the controller; raise ConnectionError with a hint."""
        if self._connected:
            return
        self._open_link(self.device, self.hint)
        self._generation = self.link.opens
        self._connected = True
        self._fault = None
        self._quit.clear()
        self._worker = threading.Thread(target=self._run, name=f"{self.device} I/O", daemon=True)
        self._worker.start()

    def disconnect(self) -> None:
        """Flush the latched targets (briefly), stop the I/O thread, close the port (idempotent).

        The controller keeps its last targets.
        """
        if self._worker is not None:
            self.flush(FLUSH_S)
            self._quit.set()
            self._wake.set()
            self._worker.join(FLUSH_S)
            self._worker = None
        self._connected = False
        self.link.close()

    def flush(self, timeout_s: float) -> bool:
        """Wait up to `timeout_s` until the latched targets are written; True if they are."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self._state:
                if not self._pending:
                    return True
            self._wake.set()
            time.sleep(0.005)
        return False

    def send(self, targets: ServoTargets) -> ServoTargets:
        """Enforce the limits, latch and write the targets; return what was applied.

        A link failure does not raise: it is reported in `fault` and the targets are re-sent
        by `poll()` once the controller is back.
        """
        if not self._connected:
            raise ServoNotConnectedError(f"the {self.device} is not connected; call connect()")
        applied = enforce_limits(targets, self.calibration)
        with self._state:
            self._latched = applied
            self._pending = True
        self._wake.set()  # the I/O thread writes them; this call never waits for the device
        return applied

    def settle(self, timeout_s: float) -> bool:
        """Wait up to `timeout_s` until the I/O thread has done all it was asked (tests, tools)."""
        with self._cycled:
            return self._cycled.wait_for(
                lambda: not self._busy and not self._wake.is_set(), timeout_s
            )

    def poll(self, wait_s: float = 0.0) -> str | None:
        """Ask the I/O thread for a health check; return `fault` (after the check if `wait_s`).

        The service never waits (its tick must not block); a test may wait up to `wait_s` for
        the check to complete.
        """
        if not self._connected:
            return self._fault
        with self._cycled:
            target = self._cycles + 1
        self._wake.set()
        if wait_s > 0:
            with self._cycled:
                self._cycled.wait_for(lambda: self._cycles >= target, wait_s)
        return self._fault

    # -- protocol hooks ------------------------------------------------------------------------
    @classmethod
    @abstractmethod
    def default_config(cls) -> ConfigT:
        """The controller's configuration when none is given."""

    @abstractmethod
    def _write_targets(self, targets: ServoTargets) -> str | None:
        """Write targets and confirm; return a controller-reported fault or None."""

    @abstractmethod
    def _probe(self) -> str | None:
        """Check the controller answers; return a controller-reported fault or None."""

    # -- internals -----------------------------------------------------------------------------
    def _run(self) -> None:
        """The I/O thread: write the latched targets, or probe the controller, when woken."""
        while not self._quit.is_set():
            self._wake.wait()
            with self._cycled:
                self._busy = True
                self._wake.clear()
            if self._quit.is_set():
                return
            try:
                self._sync()
            except Exception:  # the I/O thread must outlive any device surprise
                log.exception("%s on %s: I/O failed", self.device, self.link.port)
                with self._state:
                    self._fault = f"{self.device}: unexpected I/O error (see the log)"
            with self._cycled:
                self._cycles += 1
                self._busy = False
                self._cycled.notify_all()

    def _sync(self) -> None:
        if not self.link.ensure_open():
            self._fault = self.link.fault or f"{self.link.port} is closed"
            return
        with self._state:
            latched, pending = self._latched, self._pending
        try:
            if self.link.opens != self._generation:
                self._initialise()
                self._generation = self.link.opens
                pending = latched is not None
                log.info("%s on %s initialised again after reopen", self.device, self.link.port)
            if pending and latched is not None:
                device_fault = self._write_targets(latched)
            else:
                device_fault = self._probe()
        except LinkError as exc:
            with self._state:
                self._fault = f"{self.device}: {exc}"
                self._pending = self._latched is not None
            return
        self.link.ok()
        with self._state:
            if device_fault is not None:
                self._fault = f"{self.device}: {device_fault}"
                # The controller may have dropped or replaced the targets: write them again.
                self._pending = self._latched is not None
            else:
                self._fault = None
                # Done unless newer targets were latched while these were being written.
                self._pending = self._latched is not latched
