"""One rig, one conductor: a second `nod experiment` on a rig is refused at start in one line."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from services.core.keys import Keys
from tests.processes import run_nod, stop_all

from .conftest import ROOT

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")


def _alive(session, service: str) -> bool:
    return any(r.ok is not None for r in session.liveliness().get(KEYS.alive(service), timeout=0.5))


def test_a_second_conductor_is_refused_and_the_first_keeps_running(router, endpoint, tmp_path):
    first = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "experiment", "--connect", endpoint,
         "--db", str(tmp_path / "a.sqlite"), "--participant", "P01", "--clicks", "none",
         "--wait-services", "120", "--console", "off"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 30
        while not _alive(router, "experiment"):  # the first conductor is up (waiting for peers)
            assert time.monotonic() < deadline, "the first conductor never declared itself"
            assert first.poll() is None, "the first conductor exited"
        second = run_nod("experiment", "--connect", endpoint, "--db", str(tmp_path / "b.sqlite"),
                         "--participant", "P02", "--clicks", "none", "--console", "off",
                         timeout=60)
        assert second.returncode == 2
        lines = [ln for ln in second.stderr.splitlines() if ln.startswith("nod experiment:")]
        assert len(lines) == 1 and "another conductor is running on rig 'rig1'" in lines[0], (
            second.stderr
        )
        assert first.poll() is None and _alive(router, "experiment")  # the first goes on
        assert not (tmp_path / "b.sqlite").exists() or "P02" not in (
            (tmp_path / "b.sqlite").read_bytes().decode("latin-1")
        )  # nothing stored for the refused one
    finally:
        stop_all([first])


def test_a_wrong_rig_says_which_rigs_are_there(router, endpoint, spawn, tmp_path):
    spawn("decision", "--rig", "rigA")
    deadline = time.monotonic() + 30
    while not any(r.ok is not None for r in router.liveliness().get(
            Keys("rigA").alive("decision"), timeout=0.5)):
        assert time.monotonic() < deadline, "decision never came up on rigA"
    res = run_nod("experiment", "--connect", endpoint, "--rig", "rigB", "--db",
                  str(tmp_path / "w.sqlite"), "--wait-services", "4", "--console", "off",
                  "--clicks", "none", timeout=60)
    assert res.returncode == 1
    line = [ln for ln in res.stderr.splitlines() if ln.startswith("nod experiment:")]
    assert len(line) == 1 and "on this router: rigA (decision)" in line[0], res.stderr
