"""The conductor refuses a rig whose decision service runs other parameters; same ones: it runs.

Real processes on a real router: decision, actuation, eyes and the sim participant, the conductor
started from a rig file (`nod experiment --rig-file`: its router and params). Each service's
heartbeat carries the hash of its parameters.
"""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from services.core import messages as m
from services.core.config import load_params, params_hash
from services.core.keys import Keys
from tests.processes import stop_all

from .conftest import ROOT, SHORT, Collector, wait_for

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")


def _conductor(tmp_path, rig, name: str, *extra: str) -> subprocess.Popen:
    log = (tmp_path / f"{name}.log").open("w")
    return subprocess.Popen(
        [sys.executable, "-m", "services.cli", "experiment", "--rig-file", str(rig),
         "--db", str(tmp_path / "s.sqlite"), "--clicks", "10", "--console", "lines", *extra],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=log, stdin=subprocess.DEVNULL,
    )


def test_the_conductor_refuses_a_decision_with_other_params(router, endpoint, client, spawn,
                                                            tmp_path):
    ours, other = tmp_path / "short.toml", tmp_path / "other.toml"
    ours.write_text(SHORT)
    other.write_text(SHORT + "\n[decision.bias]\nsigma = 0.2\n")
    own, theirs = params_hash(load_params(ours)), params_hash(load_params(other))
    assert own != theirs
    rig = tmp_path / "rig.toml"
    rig.write_text(f'[rig]\nrouter = "{endpoint}"\nparams = "short.toml"\n[hosts.one]\n'
                   'services = ["decision", "actuation", "eyes", "sim"]\n')
    status = Collector(client, KEYS.topic("rig/status"), m.NodeStatus)
    decision = spawn("decision", "--params", str(other))
    for service in ("actuation", "eyes", "sim"):
        spawn(service, "--params", str(ours))
    conductors: list[subprocess.Popen] = []
    try:
        heard = wait_for(lambda: {s.service: s.params_hash for _, s in status.items}
                         if {"decision", "actuation"} <= {s.service for _, s in status.items}
                         else None, 60, "the heartbeats of decision and actuation")
        assert heard["decision"] == theirs and heard["actuation"] == own
        refused = _conductor(tmp_path, rig, "refused")
        conductors.append(refused)
        assert refused.wait(90) == 2
        lines = [ln for ln in (tmp_path / "refused.log").read_text().splitlines()
                 if "other parameters" in ln]
        assert len(lines) == 1, (tmp_path / "refused.log").read_text()[-3000:]
        assert lines[0].startswith(f"nod experiment: decision (params hash {theirs}) runs other "
                                   f"parameters than this conductor (params hash {own}, from ")
        assert "actuation" not in lines[0].split("from")[0], lines[0]
        print(f"\n{lines[0]}")

        decision.terminate()
        decision.wait(10)
        spawn("decision", "--params", str(ours))
        t0 = time.monotonic()
        wait_for(lambda: any(s.service == "decision" and s.params_hash == own
                             for t, s in status.items if t > t0), 60, "decision with our params")
        runs = _conductor(tmp_path, rig, "runs")
        conductors.append(runs)
        log = tmp_path / "runs.log"
        wait_for(lambda: "run this conductor's parameters" in log.read_text()
                 and "trials 1-3" in log.read_text(), 90, "the conductor past its params check")
        assert runs.poll() is None and "other parameters" not in log.read_text()
        assert any(s.service == "experiment" and s.params_hash == own for _, s in status.items)
    finally:
        stop_all(conductors)  # the services: the spawn fixture
