"""Fixtures for every test."""

from __future__ import annotations

import pytest

from services.safety.latch_file import STATE_DIR_ENV


@pytest.fixture(autouse=True)
def _own_state_dir(tmp_path_factory, monkeypatch):
    """Every test's devices keep their e-stop latch in a folder of that test's own.

    Services started by a test inherit it, so a latch engaged in one test never holds the
    devices of another (nor a lab's real ~/.local/state/nod).
    """
    monkeypatch.setenv(STATE_DIR_ENV, str(tmp_path_factory.mktemp("nod-state")))
