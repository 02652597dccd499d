"""A tiny progress bar on stderr for long computations (no third-party dependency)."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class ProgressBar:
    """Callable progress reporter: `bar(fraction)` redraws `label [#####.....]  50%` in place.

    Draws only when enabled — by default when the stream is a terminal, so logs and captured
    output stay clean — and at most every `min_interval` seconds. `close()` ends the line.
    """

    def __init__(
        self,
        label: str,
        stream: TextIO | None = None,
        enabled: bool | None = None,
        width: int = 30,
        min_interval: float = 0.1,
    ) -> None:
        self._stream = stream if stream is not None else sys.stderr
        if enabled is None:
            isatty = getattr(self._stream, "isatty", None)
            enabled = bool(isatty and isatty())
        self._enabled = enabled
        self._label = label
        self._width = width
        self._min_interval = min_interval
        self._last = -float("inf")
        self._drawn = False

    def __call__(self, fraction: float) -> None:
        """Report progress in [0, 1]; redraws are throttled except for the final 100 %."""
        if not self._enabled:
            return
        fraction = min(max(float(fraction), 0.0), 1.0)
        now = time.monotonic()
        if fraction < 1.0 and now - self._last < self._min_interval:
            return
        self._last = now
        filled = int(round(fraction * self._width))
        bar = "#" * filled + "." * (self._width - filled)
        self._stream.write(f"\r{self._label} [{bar}] {fraction * 100:3.0f}%")
        self._stream.flush()
        self._drawn = True

    def close(self) -> None:
        """Finish the line if anything was drawn."""
        if self._drawn:
            self._stream.write("\n")
            self._stream.flush()
            self._drawn = False
