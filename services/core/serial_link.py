"""A serial port that reopens itself: the one reconnect-with-backoff wrapper of every driver.

`SerialLink` owns a pyserial port. Every read and write goes through it, so it sees the two ways
a USB serial device fails in a lab:

- the port vanishes (cable pulled, device reset, adapter re-enumerated): pyserial raises, the
  link closes the port and schedules a reopen;
- the device stops answering: a read returns short. Each timeout is reported; after
  `max_timeouts` in a row the link also closes and reopens the port (a hung USB adapter often
  recovers that way).

Reopening never blocks the caller: `ensure_open()` tries again only once the current backoff
delay has passed (`backoff_initial_s`, multiplied by `backoff_factor` after every failed attempt,
capped at `backoff_max_s`). `opens` counts successful opens, so a driver knows when the device
behind a reopened port must be initialised again. `fault` says, in one line, what is wrong and
what the link will do about it — the string services publish on their state key.

The clock and the sleep function are injectable: unit tests drive the backoff without waiting.

`LinkedDevice` is the driver side every device on a link shares (the Feetech arm, the servo
controllers): connected while faulted, a `fault` string, and one `connect` failure message.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from abc import abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import serial

from services.model.checks import require_positive
from services.model.device import Device

try:  # POSIX: pyserial lets termios.error escape from flush/ioctl calls on a vanished tty
    import termios

    _PORT_ERRORS: tuple[type[Exception], ...] = (serial.SerialException, OSError, termios.error)
except ImportError:  # pragma: no cover - Windows
    _PORT_ERRORS = (serial.SerialException, OSError)
_OPEN_ERRORS: tuple[type[Exception], ...] = (*_PORT_ERRORS, ValueError)  # ValueError: a bad setting

log = logging.getLogger(__name__)


class LinkError(ConnectionError):
    """A serial transaction failed; the message says what happened and how the link reacts."""


class LinkLostError(LinkError):
    """The port is closed or vanished; the link reopens it with backoff."""


class LinkTimeoutError(LinkError):
    """The device did not answer in time."""


class LinkCorruptError(LinkError):
    """A reply arrived but failed its checksum or framing (the protocol layer raises this)."""


class SerialPort(Protocol):
    """The part of `serial.Serial` the link uses (a fake in tests may implement only this)."""

    def read(self, size: int = 1) -> bytes:
        """Up to `size` bytes, fewer when the port's timeout expires."""
        ...

    def write(self, data: bytes) -> int | None:
        """Send bytes; the number written."""
        ...

    def reset_input_buffer(self) -> None:
        """Drop unread input."""
        ...

    def close(self) -> None:
        """Release the device."""
        ...


# (port, baudrate, read timeout s, write timeout s) -> an open port; raises when it cannot open.
SerialFactory = Callable[[str, int, float, float], SerialPort]


@dataclass(frozen=True, slots=True)
class LinkConfig:
    """Timeouts and reconnect policy of one serial link."""

    # Time to wait for a reply (s); > 0. Bounds every read: a silent device costs at most this
    # per attempt (Feetech status packets are read in two parts, so up to twice this).
    timeout_s: float = 0.1
    # Time a write may block (s); > 0. A write that cannot drain means the device is gone.
    write_timeout_s: float = 0.5
    # First delay before reopening a lost port (s); > 0.
    backoff_initial_s: float = 0.2
    # Growth of the delay after each failed reopen; >= 1.
    backoff_factor: float = 2.0
    # Longest delay between reopen attempts (s); >= backoff_initial_s.
    backoff_max_s: float = 5.0
    # Consecutive reply timeouts after which the port is closed and reopened; >= 1.
    max_timeouts: int = 3

    def __post_init__(self) -> None:
        require_positive(self, "timeout_s", "write_timeout_s", "backoff_initial_s", "backoff_max_s")
        if not math.isfinite(self.backoff_factor) or self.backoff_factor < 1:
            raise ValueError(f"LinkConfig.backoff_factor must be >= 1, got {self.backoff_factor}")
        if self.backoff_max_s < self.backoff_initial_s:
            raise ValueError("LinkConfig.backoff_max_s must be >= backoff_initial_s")
        if isinstance(self.max_timeouts, bool) or self.max_timeouts < 1:
            raise ValueError(
                f"LinkConfig.max_timeouts must be an integer >= 1, got {self.max_timeouts}"
            )


def _pyserial(port: str, baudrate: int, timeout: float, write_timeout: float) -> SerialPort:
    # exclusive=True: a second process opening the same device fails loudly instead of
    # interleaving bytes with ours.
    return serial.Serial(
        port, baudrate, timeout=timeout, write_timeout=write_timeout, exclusive=True
    )


class SerialLink:
    """A serial port with bounded reads, fault reporting and non-blocking reopen with backoff."""

    def __init__(
        self,
        port: str,
        baudrate: int,
        config: LinkConfig | None = None,
        *,
        serial_factory: SerialFactory | None = None,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        """Describe the port; nothing is opened until `open()`."""
        if not port:
            raise ValueError("a serial port path is required (e.g. /dev/ttyACM0)")
        if baudrate <= 0:
            raise ValueError(f"baudrate must be > 0, got {baudrate}")
        self.port = port
        self.baudrate = baudrate
        self.config = config if config is not None else LinkConfig()
        self._factory = serial_factory if serial_factory is not None else _pyserial
        self.clock = clock  # monotonic seconds; protocols use it for their own deadlines
        self._sleep = sleep
        self._ser: SerialPort | None = None
        self._retry_at = 0.0
        self._delay = self.config.backoff_initial_s
        self._attempts = 0
        self._timeouts = 0
        self.opens = 0  # successful opens so far: a change means "initialise the device again"
        self.fault: str | None = None

    # -- lifetime ------------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        """Whether the port is open right now."""
        return self._ser is not None

    def open(self) -> None:
        """Open the port now; raise `LinkLostError` (with a hint) when it cannot be opened."""
        if self._ser is not None:
            return
        c = self.config
        try:
            self._ser = self._factory(self.port, self.baudrate, c.timeout_s, c.write_timeout_s)
        except _OPEN_ERRORS as exc:
            self._schedule_retry(f"cannot open {self.port}: {exc}")
            raise LinkLostError(
                f"cannot open serial port {self.port} ({exc}); check the cable, the --port "
                f"path and that no other program holds the port"
            ) from None
        self.opens += 1
        self._attempts = 0
        self._timeouts = 0
        self._delay = c.backoff_initial_s
        if self.fault is not None:
            log.info("serial port %s reopened", self.port)
        self.fault = None

    def close(self) -> None:
        """Close the port (idempotent); no reopen is scheduled."""
        ser, self._ser = self._ser, None
        if ser is not None:
            # Best effort: the device may already be gone, and closing must never fail.
            with contextlib.suppress(*_PORT_ERRORS):
                ser.close()

    def ensure_open(self) -> bool:
        """Reopen a lost port if its backoff delay has passed; True when the port is open."""
        if self._ser is not None:
            return True
        if self.clock() < self._retry_at:
            return False
        try:
            self.open()
        except LinkLostError:
            return False
        return True

    def wait_open(self, timeout_s: float) -> bool:
        """Block up to `timeout_s` (s) until the port is open again, retrying with backoff."""
        deadline = self.clock() + timeout_s
        while not self.ensure_open():
            remaining = deadline - self.clock()
            if remaining <= 0:
                return False
            self._sleep(max(0.0, min(self._retry_at - self.clock(), remaining)))
        return True

    # -- transfers -----------------------------------------------------------------------------
    def write(self, data: bytes) -> None:
        """Write all bytes; raise `LinkLostError` when the port is closed or vanished."""
        ser = self._require_open()
        try:
            written = ser.write(data)
        except serial.SerialTimeoutException as exc:
            raise self._lost(f"write to {self.port} timed out ({exc})") from None
        except _PORT_ERRORS as exc:
            raise self._lost(f"write to {self.port} failed ({exc})") from None
        if written is not None and written != len(data):
            raise self._lost(f"short write to {self.port}: {written} of {len(data)} bytes")

    def read_exact(self, n: int, what: str = "reply", *, counted: bool = True) -> bytes:
        """Read exactly n bytes within the reply timeout, else raise `LinkTimeoutError`.

        `counted=False` keeps an expected silence (a device still booting) from counting
        toward `max_timeouts`.
        """
        ser = self._require_open()
        try:
            data = bytes(ser.read(n))
        except _PORT_ERRORS as exc:
            raise self._lost(f"read from {self.port} failed ({exc})") from None
        if len(data) < n:
            self._timeouts += 1 if counted else 0
            msg = (
                f"no {what} from {self.port} within {self.config.timeout_s * 1e3:.0f} ms "
                f"(got {len(data)} of {n} bytes)"
            )
            if self._timeouts >= self.config.max_timeouts:
                raise LinkTimeoutError(str(self._lost(f"{msg}, {self._timeouts} times in a row")))
            self.fault = msg
            raise LinkTimeoutError(msg)
        return data

    def discard_input(self) -> None:
        """Drop unread input (stale or corrupt bytes) before a new request."""
        ser = self._require_open()
        try:
            ser.reset_input_buffer()
        except _PORT_ERRORS as exc:
            raise self._lost(f"flush of {self.port} failed ({exc})") from None

    def transact(
        self, request: bytes, reply_len: int, what: str = "reply", *, counted: bool = True
    ) -> bytes:
        """Drop stale input, send a request and read a fixed-length reply."""
        self.discard_input()
        self.write(request)
        return self.read_exact(reply_len, what, counted=counted)

    def report(self, message: str) -> None:
        """Record a protocol-level fault (bad checksum, device error) without closing the port."""
        self.fault = message

    def ok(self) -> None:
        """A transaction succeeded: clear the timeout count and the fault."""
        self._timeouts = 0
        self.fault = None

    # -- internals -----------------------------------------------------------------------------
    def _require_open(self) -> SerialPort:
        if self._ser is None:
            raise LinkLostError(self.fault or f"serial port {self.port} is not open")
        return self._ser

    def _lost(self, reason: str) -> LinkLostError:
        """Close the port, schedule a reopen and return the error to raise."""
        self.close()
        self._timeouts = 0
        self._schedule_retry(reason)
        log.warning("%s", self.fault)
        return LinkLostError(self.fault or reason)

    def _schedule_retry(self, reason: str) -> None:
        if self._attempts > 0:
            self._delay = min(self._delay * self.config.backoff_factor, self.config.backoff_max_s)
        self._attempts += 1
        self._retry_at = self.clock() + self._delay
        self.fault = (
            f"{reason}; reopening {self.port} in {self._delay:.2g} s (attempt {self._attempts})"
        )

    def __repr__(self) -> str:
        state = "open" if self.is_open else "closed"
        return f"SerialLink({self.port!r}, {self.baudrate}, {state}, fault={self.fault!r})"


class LinkedDevice(Device):
    """A device driven over one `SerialLink`: what the Feetech arm and the servo drivers share.

    Connected from `connect()` to `disconnect()`, also while the link is faulted: once
    connected, a driver never raises on a link failure; it says what is wrong in `fault` (one
    line, the string its service publishes) and recovers on its own. Only `connect()` raises,
    naming the device, the port and how to fix it, so a wrong cable or baud rate is found at once.
    """

    link: SerialLink
    _connected: bool = False
    _fault: str | None = None

    @property
    def is_connected(self) -> bool:
        """True between `connect()` and `disconnect()`, also while the link is faulted."""
        return self._connected

    @property
    def fault(self) -> str | None:
        """What is wrong with the link or the device, or None when healthy."""
        return self._fault

    @abstractmethod
    def _initialise(self) -> None:
        """Configure a freshly opened device; raise `LinkError` if it does not answer."""

    def _open_link(self, device: str, hint: str) -> None:
        """Open the port and `_initialise` the device, or close it and raise ConnectionError.

        The message names the device, the port and the fix: "<device> on <port> did not answer
        (<why>); <hint>".
        """
        self.link.open()
        try:
            self._initialise()
        except LinkError as exc:
            self.link.close()
            raise ConnectionError(
                f"{device} on {self.link.port} did not answer ({exc}); {hint}"
            ) from None
