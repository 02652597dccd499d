"""Valid-but-forged protocol messages on an open network: the conductor's own checks refuse them.

(On a lab network the access control of `nod lab secure` refuses them before they get here.)
"""

from __future__ import annotations

import re
import subprocess
import sys
import threading
import time

import pytest

from services.core import messages as m
from services.core.keys import Keys
from services.store import Store

from .conftest import ROOT, connect_when_listening, free_port

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")
SHORT = """
[protocol]
max_attempts = 1
[[protocol.trials]]
index = 1
mode = "dissensus"
gaze_level = "neutral"
[[protocol.trials]]
index = 2
mode = "consensus"
option = "red"
gaze_level = "low"
[[protocol.trials]]
index = 3
mode = "consensus"
option = "blue"
gaze_level = "significant"
"""


def _session_with(tmp_path, attack) -> tuple[subprocess.CompletedProcess, Store, str]:
    params = tmp_path / "short.toml"
    params.write_text(SHORT)
    db, logs = tmp_path / "s.sqlite", tmp_path / "logs"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cmd = [sys.executable, "-m", "services.cli", "run", "--sim", "--speed", "4", "--seed", "4",
           "--db", str(db), "--listen", endpoint, "--logs", str(logs), "--params", str(params),
           "--stale-ms", "1000"]
    stop = threading.Event()
    run = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           text=True)
    attacker = threading.Thread(target=attack, args=(endpoint, stop), daemon=True)
    attacker.start()
    try:
        out, _ = run.communicate(timeout=240)
    finally:
        stop.set()
        attacker.join(10)
        if run.poll() is None:
            run.kill()
    assert run.returncode == 0, out
    logs_text = "".join(p.read_text() for p in sorted(logs.glob("*.log")))
    return run, Store(db), logs_text


def test_forged_robot_presses_are_refused(tmp_path):
    def attack(endpoint: str, stop: threading.Event) -> None:
        session = connect_when_listening(endpoint)
        press = session.declare_publisher(KEYS.topic("actuation/press"))
        seq = 0
        while not stop.wait(0.02):  # both buzzers, every trial, 50 times a second
            for trial in (1, 2, 3):
                for colour in ("red", "blue"):
                    seq += 1
                    msg = m.PressMsg(seq=seq, t_ns=time.time_ns(), colour=colour, trial=trial)
                    press.put(m.encode(msg))
        session.close()

    _, store, logs = _session_with(tmp_path, attack)
    try:
        trials = [t for _, t in store.trials()]
        session = store.sessions()[-1]["session"]
        context = (store.interruptions(session), store.safety_events(session)[:10])
    finally:
        store.close()
    real = {int(n): c for n, c in re.findall(r"trial (\d+): robot pressed (red|blue)", logs)}
    assert [t.trial for t in trials] == [1, 2, 3]
    # What the arm did, not what was forged.
    assert {t.trial: t.robot for t in trials} == real, (trials, context)
    assert "never confirmed by actuation/state" in logs and "refused" in logs


def test_a_second_hand_stream_voids_the_trials_instead_of_scoring_them(tmp_path):
    def attack(endpoint: str, stop: threading.Event) -> None:
        session = connect_when_listening(endpoint)
        hand = session.declare_publisher(KEYS.topic("vision/hand"))
        seq = 0
        while not stop.wait(1 / 30):  # a hand parked on the red buzzer, with its own numbering
            seq += 1
            pose = m.HandPose(
                seq=seq, t_ns=time.time_ns(), detected=True, center=(0.79, 0.19),
                landmarks=((0.79, 0.19),), source="intruder",
            )
            hand.put(m.encode(pose))
        session.close()

    _, store, _ = _session_with(tmp_path, attack)
    try:
        trials = [t for _, t in store.trials()]
        session = store.sessions()[-1]["session"]
        broken = store.interruptions(session)
    finally:
        store.close()
    assert [t.trial for t in trials] == [1, 2, 3]
    assert all(t.interrupted and t.outcome is None and t.score == 0 for t in trials), trials
    assert all("two publishers on vision/hand" in b.reason for b in broken), broken
