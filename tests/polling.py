"""The tests' one way to wait for something: poll a check until it holds, never a fixed sleep."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def eventually(check: Callable[[], T], timeout_s: float = 5.0, every_s: float = 0.01) -> T | None:
    """Call `check` until it returns something true and return that; None after `timeout_s`.

    `check` runs at least once, and its last run comes after the deadline: a generous bound, as
    the machine may be loaded.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() >= deadline:
            return None
        time.sleep(every_s)


def wait_for(check: Callable[[], T], timeout: float, what: str, every_s: float = 0.01) -> T:
    """`eventually`, failing the test with `what` after `timeout` seconds; check()'s true value."""
    value = eventually(check, timeout, every_s)
    if not value:
        raise AssertionError(f"timed out after {timeout} s waiting for {what}")
    return value
