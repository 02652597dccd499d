"""What a `with` block does with a device or any resource: acquire on entry, release on exit.

`Scoped` is the one `__enter__`/`__exit__` of the project's resources (a hand tracker's model,
an emulated device's pty or process, a driver's port): entering calls `_on_enter` and returns
the object, leaving calls `_on_exit` whatever happened (an exception is never swallowed).

`Device` is the interface hardware shares, after LeRobot's `Robot`: `connect / is_connected /
disconnect`, and a `with` block that leaves the device in its safe state (the arm held, the
eyes neutral) before it disconnects, so an exception in the block never leaves a servo driven.
`SimConnection` is the connection of a simulated device: a flag, nothing to open.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from types import TracebackType
from typing import Self


class Scoped:
    """A resource a `with` block acquires (`_on_enter`) and always releases (`_on_exit`)."""

    def _on_enter(self) -> None:
        """Acquire the resource (default: nothing, the constructor did)."""

    def _on_exit(self) -> None:
        """Release the resource; idempotent."""

    def __enter__(self) -> Self:
        self._on_enter()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._on_exit()


class Device(Scoped, ABC):
    """Hardware behind `connect / is_connected / disconnect`, left safe by a `with` block."""

    @property
    @abstractmethod
    def is_connected(self) -> bool:
        """Whether commands can be sent."""

    @abstractmethod
    def connect(self) -> None:
        """Open the connection to the device (idempotent)."""

    @abstractmethod
    def disconnect(self) -> None:
        """Close the connection (idempotent); callers put the device in its safe state first."""

    @abstractmethod
    def make_safe(self) -> object:
        """Put the device in its safe state (what leaving a `with` block does before closing)."""

    def _on_enter(self) -> None:
        self.connect()

    def _on_exit(self) -> None:
        try:
            if self.is_connected:
                self.make_safe()
        finally:
            self.disconnect()


class SimConnection:
    """The connection of a simulated device: a flag that `connect` sets, nothing to open.

    Mixed in before the `Device` interface, it provides its three connection members.
    """

    _connected: bool = False

    @property
    def is_connected(self) -> bool:
        """Whether commands can be sent."""
        return self._connected

    def connect(self) -> None:
        """Mark the simulated device connected."""
        self._connected = True

    def disconnect(self) -> None:
        """Mark the simulated device disconnected; its state (pose, record) is kept."""
        self._connected = False
