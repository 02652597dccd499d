"""A launcher's logs: one new folder per run, and the lines of a log the operator must see.

`nod run` (and `nod study start --sim`, which runs it) writes each run's service logs to a
folder of its own, `<db>.logs/<YYYYmmdd-HHMMSS>/` (`-2`, `-3`, … when two runs start within
the same second): a later run or participant never overwrites the evidence of an earlier one.
`LogWatch` follows a log as it grows and hands back the new lines that match, so a launcher
can say in its own terminal what a service says only in its log (a trial waiting for the
operator's `nod experiment next`).
"""

from __future__ import annotations

import itertools
import re
import time
from pathlib import Path

# What the conductor logs when a trial waits at the operator's gate (services.experiment.
# operator.OperatorGate.step): `trial 3 ready: waiting for the operator — … starts it`.
WAITING = re.compile(r"(trial \d+(?: \(attempt \d+\))? ready: waiting for the operator.*)$")


def run_folder(base: Path, now: float | None = None) -> Path:
    """A new, empty folder under `base` for one run's logs, named by the run's start time.

    Never one that exists (made with `mkdir` without `exist_ok`, so two runs started in the
    same second, even at once, get two folders). OSError if `base` cannot be written.
    """
    base.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
    for k in itertools.count(1):
        path = base / (stamp if k == 1 else f"{stamp}-{k}")
        try:
            path.mkdir()
        except FileExistsError:
            continue
        return path
    raise AssertionError("unreachable")  # pragma: no cover


class LogWatch:
    """The new lines of a growing log that match `pattern` (its first group, or the match).

    Reads from where it last stopped, whole lines only; a log that does not exist yet, or was
    truncated (a fresh log of a restarted run), is read from its start. A line repeated right
    after itself (a restarted service saying it again) is handed back once.
    """

    def __init__(self, path: Path, pattern: re.Pattern[str] = WAITING) -> None:
        self.path = path
        self.pattern = pattern
        self._offset = 0
        self._partial = b""
        self._last: str | None = None

    def new(self) -> list[str]:
        """The matching lines written since the last call."""
        try:
            with self.path.open("rb") as fh:
                fh.seek(0, 2)
                if fh.tell() < self._offset:  # truncated: a new log
                    self._offset, self._partial = 0, b""
                fh.seek(self._offset)
                chunk = fh.read()
        except OSError:
            return []
        self._offset += len(chunk)
        *lines, self._partial = (self._partial + chunk).split(b"\n")
        out = []
        for raw in lines:
            found = self.pattern.search(raw.decode("utf-8", "replace").rstrip("\r"))
            if found is None:
                continue
            text = found.group(1) if found.groups() else found.group(0)
            if text != self._last:
                out.append(text)
            self._last = text
        return out
