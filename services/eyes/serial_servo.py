"""What every servo driver on a serial port shares: latched targets, reconnect and a fault string.

A serial servo driver never raises on a link failure once connected: `send()` enforces the
calibration's limits, latches the targets and tries to write them; when the port has vanished or
the controller is silent, `fault` says so and the targets stay latched. `poll()` (called by the
service a few times a second) reopens the port with backoff, initialises the controller again
after a reopen and re-sends the latched targets, so the eyes end where they were told to look.
"""

from __future__ import annotations

import logging
from abc import abstractmethod

from services.core.serial_link import LinkError, SerialLink
from services.eyes.servos import ServoDriver, ServoNotConnectedError
from services.model.servos import EyesCalibration, ServoTargets, enforce_limits

log = logging.getLogger(__name__)


class SerialServoDriver(ServoDriver):
    """Base of the Maestro and Arduino drivers; subclasses speak the protocol."""

    #: Human name of the controller, for messages.
    device = "servo controller"
    #: How to fix a controller that does not answer at connect time.
    hint = "check the cable, the --port path and the baud rate"

    def __init__(self, link: SerialLink, calibration: EyesCalibration | None = None) -> None:
        """Drive servos through `link` (not opened until `connect()`)."""
        super().__init__(calibration)
        self.link = link
        self._connected = False
        self._generation = -1  # link.opens at the last initialisation of the controller
        self._latched: ServoTargets | None = None
        self._pending = False  # latched targets not yet confirmed written
        self._fault: str | None = None

    # -- interface -----------------------------------------------------------------------------
    @property
    def is_connected(self) -> bool:
        """True between `connect()` and `disconnect()`, also while the link is faulted."""
        return self._connected

    @property
    def fault(self) -> str | None:
        """What is wrong with the link or the controller, or None when healthy."""
        return self._fault

    @property
    def latched(self) -> ServoTargets | None:
        """The targets the driver holds the servos at (re-sent after a reconnect)."""
        return self._latched

    def connect(self) -> None:
        """Open the port and initialise the controller; raise ConnectionError with a hint."""
        if self._connected:
            return
        self.link.open()
        try:
            self._initialise()
        except LinkError as exc:
            self.link.close()
            raise ConnectionError(
                f"{self.device} on {self.link.port} did not answer ({exc}); {self.hint}"
            ) from None
        self._generation = self.link.opens
        self._connected = True
        self._fault = None

    def disconnect(self) -> None:
        """Close the port (idempotent); the controller keeps its last targets."""
        self._connected = False
        self.link.close()

    def send(self, targets: ServoTargets) -> ServoTargets:
        """Enforce the limits, latch and write the targets; return what was applied.

        A link failure does not raise: it is reported in `fault` and the targets are re-sent
        by `poll()` once the controller is back.
        """
        if not self._connected:
            raise ServoNotConnectedError(f"the {self.device} is not connected; call connect()")
        applied = enforce_limits(targets, self.calibration)
        self._latched = applied
        self._pending = True
        self._sync()
        return applied

    def poll(self) -> str | None:
        """Reconnect if needed, re-send latched targets, probe the controller; return `fault`."""
        if self._connected:
            self._sync()
        return self._fault

    # -- protocol hooks ------------------------------------------------------------------------
    @abstractmethod
    def _initialise(self) -> None:
        """Configure a freshly opened controller; raise `LinkError` if it does not answer."""

    @abstractmethod
    def _write_targets(self, targets: ServoTargets) -> str | None:
        """Write targets and confirm; return a controller-reported fault or None."""

    @abstractmethod
    def _probe(self) -> str | None:
        """Check the controller answers; return a controller-reported fault or None."""

    # -- internals -----------------------------------------------------------------------------
    def _sync(self) -> None:
        if not self.link.ensure_open():
            self._fault = self.link.fault or f"{self.link.port} is closed"
            return
        try:
            if self.link.opens != self._generation:
                self._initialise()
                self._generation = self.link.opens
                self._pending = self._latched is not None
                log.info("%s on %s initialised again after reopen", self.device, self.link.port)
            if self._pending and self._latched is not None:
                device_fault = self._write_targets(self._latched)
            else:
                device_fault = self._probe()
        except LinkError as exc:
            self._fault = f"{self.device}: {exc}"
            self._pending = self._latched is not None
            return
        self.link.ok()
        if device_fault is not None:
            self._fault = f"{self.device}: {device_fault}"
            # The controller may have dropped or replaced the targets: write them again next time.
            self._pending = self._latched is not None
        else:
            self._fault = None
            self._pending = False
