"""The servo driver interface every eyes driver implements, and a simulated driver.

The mapping from a gaze to servo targets, with its limits, is pure and lives in
`services.model.servos`; drivers only apply targets (after `enforce_limits` once more).
"""

from __future__ import annotations

from abc import abstractmethod

from services.model.device import Device, SimConnection
from services.model.gaze import GazeCommand
from services.model.servos import EyesCalibration, ServoTargets, enforce_limits, servo_targets


class ServoNotConnectedError(RuntimeError):
    """Targets reached a servo driver before `connect()` (or after `disconnect()`)."""


class ServoDriver(Device):
    """The interface every eyes driver (simulated, Pololu Maestro, …) implements."""

    def __init__(self, calibration: EyesCalibration | None = None) -> None:
        """Keep the calibration the driver enforces on every send."""
        self.calibration = calibration if calibration is not None else EyesCalibration()

    @abstractmethod
    def send(self, targets: ServoTargets) -> ServoTargets:
        """Drive the servos; return the targets actually applied (after `enforce_limits`)."""

    def look(self, cmd: GazeCommand) -> ServoTargets:
        """Compute the targets for a gaze and send them."""
        return self.send(servo_targets(cmd, self.calibration))

    def neutral(self) -> ServoTargets:
        """Look straight ahead (the eyes' safe state)."""
        return self.look(GazeCommand())

    def make_safe(self) -> ServoTargets:
        """Look straight ahead (before disconnecting)."""
        return self.neutral()


class SimServoDriver(SimConnection, ServoDriver):
    """A driver that records every applied target instead of moving servos."""

    def __init__(self, calibration: EyesCalibration | None = None) -> None:
        """Start disconnected with an empty record."""
        super().__init__(calibration)
        self._connected = False
        self.sent: list[ServoTargets] = []

    def send(self, targets: ServoTargets) -> ServoTargets:
        """Record the targets after enforcing the calibration's limits."""
        if not self._connected:
            raise ServoNotConnectedError("the eyes are not connected; call connect() first")
        applied = enforce_limits(targets, self.calibration)
        self.sent.append(applied)
        return applied

    @property
    def last(self) -> ServoTargets | None:
        """The latest applied targets, or None if nothing was sent."""
        return self.sent[-1] if self.sent else None
