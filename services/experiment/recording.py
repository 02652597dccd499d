"""`nod experiment --record DIR`: a `nod record` child process for the session.

The conductor starts `python -m services.cli record` with its own session flags (rig, mode,
endpoints, zenoh config; never its listen endpoints) writing `DIR/<session>.mcap`, waits until
the recorder has subscribed (its first stdout line), and stops it with SIGTERM once the session
is over, so the file gets its summary. The recorder dies with the conductor (NOD_PARENT_PID):
a conductor killed mid-session still leaves a finished file. A conductor restarted on the same
session (`--resume`) records to `DIR/<session>-2.mcap`, and so on; the store links each file to
the session (`recordings` table).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import subprocess
import threading
import time
from collections.abc import Mapping
from pathlib import Path

from services.core.lifeline import nod_command

log = logging.getLogger("nod.experiment")
READY = "nod record: recording"  # the recorder's first line once subscribed


def recording_path(folder: Path, session: str) -> Path:
    """`folder/<session>.mcap`, or `<session>-2.mcap`, ... if taken (a resumed session)."""
    path = folder / f"{session}.mcap"
    n = 2
    while path.exists():
        path = folder / f"{session}-{n}.mcap"
        n += 1
    return path


def recorder_command(
    args: argparse.Namespace, path: Path, session: str,
    provenance: Mapping[str, str] | None = None,
) -> list[str]:
    """The recorder's command line: the conductor's session flags, the session in metadata.

    And the session's provenance as it starts: the file's `provenance` metadata record.
    """
    cmd = nod_command("record", "--out", str(path), "--rig", args.rig, "--mode", args.mode)
    for endpoint in args.connect or ():
        cmd += ["--connect", endpoint]
    if args.config is not None:
        cmd += ["--config", str(args.config)]
    if args.params is not None:
        cmd += ["--params", str(args.params)]
    cmd += ["--meta", f"session={session}", "--meta", f"participant={args.participant}",
            "--meta", f"clock_speed={args.speed!r}"]
    if args.epoch_ns is not None:
        cmd += ["--meta", f"epoch_ns={args.epoch_ns}"]
    if provenance:
        cmd += ["--provenance", json.dumps(dict(provenance), sort_keys=True)]
    return cmd


class RecorderProcess:
    """A running `nod record` child."""

    def __init__(self, cmd: list[str], path: Path) -> None:
        self.path = path
        self.summary = ""
        env = {**os.environ, "NOD_PARENT_PID": str(os.getpid())}
        self.proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True, env=env
        )
        self._ready = threading.Event()
        self._reader = threading.Thread(target=self._read, name="recorder-out", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            line = line.rstrip("\n")
            if line.startswith(READY):
                self._ready.set()
            elif line:
                self.summary = line
            log.info("%s", line)

    def wait_ready(self, timeout_s: float) -> bool:
        """True once the recorder has subscribed; False if it exited or did not in time."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self._ready.wait(0.05):
                return True
            if self.proc.poll() is not None:
                return False
        return False

    def stop(self, tail_s: float = 0.5, timeout_s: float = 20.0) -> int | None:
        """Let the last messages arrive, SIGTERM, wait (SIGKILL after `timeout_s`)."""
        if self.proc.poll() is None:
            time.sleep(tail_s)
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                log.warning("recorder did not stop within %.0f s: killed", timeout_s)
                self.proc.kill()
                self.proc.wait()
        self._reader.join(2.0)
        return self.proc.returncode
