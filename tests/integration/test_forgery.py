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

from .conftest import (
    ROOT,
    SHORT,
    SHORT_THREE,
    connect_when_listening,
    free_port,
    last_session_record,
)

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")
# SHORT (two options, or three: one key space for any N) with one attempt a trial: a trial the
# attack breaks is not repeated.
ONCE = "[protocol]\nmax_attempts = 1\n"
SHORT_ONCE = {2: ONCE + SHORT, 3: SHORT_THREE.replace("[protocol]\n", ONCE, 1)}
NAMES = {2: ("red", "blue"), 3: ("red", "blue", "green")}


def _session_with(tmp_path, attack, n: int = 2) -> tuple[list, list, list, str]:
    """`nod run --sim` of SHORT_ONCE[n] while `attack(endpoint, stop)` runs on a thread: the
    session's trials, interruptions and safety events as stored, and the services' logs."""
    params = tmp_path / "short.toml"
    params.write_text(SHORT_ONCE[n])
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
    trials, broken, events = last_session_record(
        db, lambda store, session: [t for _, t in store.trials(session)])
    return trials, broken, events, logs_text


@pytest.mark.parametrize("n", [2, 3])
def test_forged_robot_presses_are_refused(tmp_path, n):
    def attack(endpoint: str, stop: threading.Event) -> None:
        session = connect_when_listening(endpoint)
        press = session.declare_publisher(KEYS.topic("actuation/press"))
        seq = 0
        while not stop.wait(0.02):  # every buzzer, every trial, 50 times a second
            for trial in (1, 2, 3):
                for option in NAMES[n]:
                    seq += 1
                    msg = m.PressMsg(seq=seq, t_ns=time.time_ns(), option=option, trial=trial)
                    press.put(m.encode(msg))
        session.close()

    trials, broken, events, logs = _session_with(tmp_path, attack, n)
    context = (broken, events[:10])
    pressed = "|".join(NAMES[n])
    real = {int(k): c for k, c in re.findall(rf"trial (\d+): robot pressed ({pressed})\b", logs)}
    assert [t.trial for t in trials] == [1, 2, 3]
    # What the arm did, not what was forged. (A loaded host may break a trial, not repeated
    # here: no press of its is stored, forged or real.)
    pressed_trials = {t.trial: t.robot for t in trials if not (t.interrupted and t.robot is None)}
    assert real and pressed_trials == real, (trials, context)
    assert "never confirmed by the arm's state" in logs and "refused" in logs


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

    trials, broken, _, _ = _session_with(tmp_path, attack)
    assert [t.trial for t in trials] == [1, 2, 3]
    assert all(t.interrupted and t.outcome is None and t.score == 0 for t in trials), trials
    assert all("two publishers on vision/hand" in b.reason for b in broken), broken
