"""One rig, one conductor: a second `nod experiment` on a rig is refused at start in one line."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from services.core.keys import Keys
from tests.processes import run_nod, stop_all

from .conftest import ROOT, wait_for

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


def _conductor(endpoint: str, db: Path, participant: str, log: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "services.cli", "experiment", "--connect", endpoint, "--db",
         str(db), "--participant", participant, "--clicks", "none", "--wait-services", "120",
         "--console", "off"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=log.open("w"), stdin=subprocess.DEVNULL,
    )


@pytest.mark.parametrize("apart_s", [0.0, 1.0])
def test_two_conductors_started_close_together_end_with_exactly_one(
    router, endpoint, tmp_path, apart_s
):
    # The audit's fault: a second conductor started within ~5 s of the first (while the first
    # waited to hear the devices, before declaring itself) was not refused; both ran.
    logs = [tmp_path / "a.log", tmp_path / "b.log"]
    first = _conductor(endpoint, tmp_path / "a.sqlite", "P01", logs[0])
    time.sleep(apart_s)  # the scenario itself: how far apart the two starts are
    second = _conductor(endpoint, tmp_path / "b.sqlite", "P02", logs[1])
    procs = [first, second]
    try:
        wait_for(lambda: sum(p.poll() is not None for p in procs) >= 1, 60,
                 "one of the two conductors giving way")
        wait_for(lambda: _alive(router, "experiment"), 30, "the other conductor declared alive")
        exited = [i for i, p in enumerate(procs) if p.poll() is not None]
        assert len(exited) == 1, [p.poll() for p in procs]
        loser = exited[0]
        assert procs[loser].returncode == 2
        said = [ln for ln in logs[loser].read_text().splitlines()
                if ln.startswith("nod experiment:")]
        assert len(said) == 1 and "another conductor is running on rig 'rig1'" in said[0], said
        assert "claimed the rig first" in said[0]
        if apart_s:
            assert loser == 1  # the later one gives way
        assert procs[1 - loser].poll() is None  # the winner goes on (waiting for the devices)
    finally:
        stop_all(procs)
