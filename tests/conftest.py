"""Fixtures for every test."""

from __future__ import annotations

import subprocess

import pytest
from hypothesis import settings

from services.safety.latch_file import STATE_DIR_ENV

# Hypothesis's per-example deadline (200 ms) measures the machine, not the code: one example
# that a loaded 2-core host delayed failed a whole test run and hid the integration tests.
# Speed is measured by the benchmarks; a property test asserts properties only.
settings.register_profile("nod", deadline=None)
settings.load_profile("nod")


@pytest.fixture(autouse=True)
def _own_state_dir(tmp_path_factory, monkeypatch):
    """Every test's devices keep their e-stop latch in a folder of that test's own.

    Services started by a test inherit it, so a latch engaged in one test never holds the
    devices of another (nor a lab's real ~/.local/state/nod).
    """
    monkeypatch.setenv(STATE_DIR_ENV, str(tmp_path_factory.mktemp("nod-state")))


@pytest.fixture
def small_disk(tmp_path):
    """A folder on a real filesystem of its own, 64 kB, that a test can fill and free.

    `fill()` writes it to its last byte: a new empty file can still be made there (inodes are
    free), but any byte written fails with ENOSPC, as on a lab controller whose disk filled up.
    `free()` empties it (the operator cleaned up). Needs root for the tmpfs (CI runs as root),
    else the test is skipped.
    """
    mount = tmp_path / "disk"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")

    class Disk:
        path = mount
        filler = mount / ".filler"

        def fill(self) -> None:
            try:
                with open(self.filler, "ab") as fh:
                    while True:
                        fh.write(b"\0" * 4096)
                        fh.flush()
            except OSError:
                pass

        def free(self) -> None:
            self.filler.unlink(missing_ok=True)

    try:
        yield Disk()
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)
