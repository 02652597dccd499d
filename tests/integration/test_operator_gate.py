"""The operator's start gate: with `gate = true` no trial starts before `nod experiment next`,
and `nod experiment pause` holds the next trial of an ungated session (real processes).

One conductor and one key space (schema 3) for any option set: the gate's tests run on the
paper's two options and on a table of three, their trial events alike on `experiment/trial`."""

from __future__ import annotations

import re
import subprocess
import time
from pathlib import Path

import pytest

from services.core import messages as m
from services.core.keys import Keys
from services.store import Store
from tests.processes import run_nod

from .conftest import SHORT, SHORT_THREE, Collector, wait_for

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")
SPEED = ("--speed", "4")
# option count: the 3-trial params
SESSIONS: dict[int, str] = {2: SHORT, 3: SHORT_THREE}
by_option_count = pytest.mark.parametrize("n", sorted(SESSIONS), ids=lambda n: f"{n} options")


def _params(n: int, gated: bool) -> str:
    """The 3-trial params of `n` options, with the operator's gate if `gated`."""
    text = SESSIONS[n]
    if not gated:
        return text
    if "[protocol]\n" in text:
        return text.replace("[protocol]\n", "[protocol]\ngate = true\n", 1)
    return text.replace("[[protocol.trials]]", "[protocol]\ngate = true\n\n[[protocol.trials]]", 1)


def _events(client) -> Collector:
    return Collector(client, KEYS.topic("experiment/trial"), m.TrialEvent)


def _rig(spawn, params: str, epoch: str) -> None:
    clock = [*SPEED, "--epoch-ns", epoch, "--params", params]
    for service in ("decision", "actuation", "eyes", "sim"):
        spawn(service, *clock)


def _setups(events: Collector) -> list[int]:
    """The trials set up so far, in order; a repeated attempt (a loaded host's stale input can
    break one, and the paper's rule repeats it) is the same trial, not a new one."""
    return list(dict.fromkeys(e.trial for e in events.messages if e.phase == "setup"))


def _session(
    spawn, client, tmp_path: Path, n: int, gated: bool
) -> tuple[subprocess.Popen, Collector, Path]:
    """A rig and a 3-trial conductor of `n` options (gated or not), each its own process: the
    conductor, its trial events and its store."""
    params = tmp_path / "params.toml"
    params.write_text(_params(n, gated))
    epoch = str(time.time_ns())
    _rig(spawn, str(params), epoch)
    events = _events(client)
    db = tmp_path / "s.sqlite"
    conductor = spawn("experiment", *SPEED, "--epoch-ns", epoch, "--params", str(params),
                      "--db", str(db), "--clicks", "10", "--console", "lines")
    return conductor, events, db


def _operator(endpoint: str, action: str) -> None:
    res = run_nod("experiment", action, "--connect", endpoint, "--timeout", "30", timeout=60)
    assert res.returncode == 0, res.stdout + res.stderr


@by_option_count
def test_a_gated_session_starts_each_trial_only_when_the_operator_says(
    router, endpoint, client, spawn, tmp_path, n
):
    conductor, events, db = _session(spawn, client, tmp_path, n, gated=True)
    for trial in (1, 2, 3):
        wait_for(lambda t=trial: f"trial {t} ready: waiting for the operator"
                 in conductor.log_path.read_text(), 60, f"trial {trial} waiting")
        # Not a wait for a condition: a bounded window in which nothing may start by itself.
        time.sleep(0.5)
        assert _setups(events) == list(range(1, trial)), _setups(events)
        _operator(endpoint, "next")
        wait_for(lambda t=trial: t in _setups(events), 10, f"trial {trial} set up")
    assert conductor.wait(60) == 0, conductor.log_path.read_text()[-2000:]
    assert {len(e.options) for e in events.messages} == {n}  # every event names the set
    store = Store(db)
    try:
        assert [t.trial for _, t in store.trials()] == [1, 2, 3]
        (session,) = [s["session"] for s in store.sessions()]
        assert len(store.option_names(session)) == n
    finally:
        store.close()


@by_option_count
def test_pause_holds_the_next_trial_of_an_ungated_session(
    router, endpoint, client, spawn, tmp_path, n
):
    conductor, events, _ = _session(spawn, client, tmp_path, n, gated=False)
    wait_for(lambda: 1 in _setups(events), 60, "trial 1 under way")
    _operator(endpoint, "pause")
    # The pause holds whichever trial comes next when it lands: trial 2, or trial 3 when a
    # loaded machine took the operator's command (a new process and session) past trial 2's
    # start. Only a pause after trial 3's start would leave nothing to hold.
    held = wait_for(lambda: re.search(r"trial (\d+) ready: waiting for the operator",
                                      conductor.log_path.read_text()), 60, "the next trial held")
    trial = int(held.group(1))
    assert trial in (2, 3), held.group(0)
    assert _setups(events) == list(range(1, trial)), (trial, _setups(events))
    _operator(endpoint, "next")
    assert conductor.wait(60) == 0, conductor.log_path.read_text()[-2000:]
    assert _setups(events) == [1, 2, 3]  # after the held trial the session went on by itself


def test_nod_run_says_when_a_trial_waits_for_the_operator(tmp_path):
    """`nod run` prints the conductor's "waiting for the operator" with the command to start it."""
    import sys
    import threading

    from tests.processes import stop_all

    from .conftest import ROOT, free_port

    params = tmp_path / "gated.toml"
    params.write_text(_params(2, gated=True))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    rig = tmp_path / "rig.toml"
    rig.write_text(f'[rig]\nname = "rig1"\nrouter = "{endpoint}"\n[hosts.here]\nrouter = true\n'
                   'services = ["decision", "actuation", "eyes", "vision"]\n')
    run = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "run", "--sim", "--speed", "4", "--params",
         str(params), "--listen", endpoint, "--stale-ms", "2000", "--db",
         str(tmp_path / "s.sqlite")],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(run.stdout.readline, "")),
                              daemon=True)
    reader.start()
    try:
        for trial in (1, 2, 3):
            wait_for(lambda t=trial: any(f"trial {t} ready: waiting for the operator" in ln
                                         for ln in lines), 90, f"nod run saying trial {trial}")
            said = next(ln for ln in lines if f"trial {trial} ready" in ln)
            assert f"(here: nod experiment next --connect {endpoint})" in said, said
            if trial == 2:  # the rig file's way in: its rig and router
                res = run_nod("experiment", "next", "--rig-file", str(rig), "--timeout", "30",
                              timeout=60)
                assert res.returncode == 0, res.stdout + res.stderr
            else:
                _operator(endpoint, "next")
        assert run.wait(120) == 0, "".join(lines)[-3000:]
    finally:
        stop_all([run])
    reader.join(5)
    assert sum("waiting for the operator" in ln for ln in lines) == 3, "".join(lines)
