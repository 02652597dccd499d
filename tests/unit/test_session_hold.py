"""The session's hold says once why it holds, and again when an e-stop turns out to hold it."""

from __future__ import annotations

import logging

import pytest

from services.experiment.hold import SessionHold
from services.experiment.rig_watch import RigWatch


def _held_lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.getMessage().startswith("session held")]


def test_an_estop_heard_during_another_hold_is_said(caplog: pytest.LogCaptureFixture) -> None:
    clock = [0]
    rig = RigWatch(monotonic=lambda: clock[0])
    hold = SessionHold(rig)
    with caplog.at_level(logging.WARNING, logger="nod.experiment"):
        assert not hold.ready(0)  # no device heard yet: held, said once
        assert not hold.ready(1)
        assert _held_lines(caplog) == ["session held: no state from actuation; no state from eyes"]
        # A restarted conductor hears of the latched e-stop after that: said, with the e-stop
        rig.estop(True, "bump", "lab", 2)
        assert not hold.ready(3) and not hold.ready(4)
        lines = _held_lines(caplog)
        assert len(lines) == 2 and lines[1].startswith("session held: e-stop engaged (bump")
        # Released, then engaged again while still held: said again
        rig.estop(False, "", "lab", 5)
        assert not hold.ready(6)
        rig.estop(True, "second", "lab", 7)
        assert not hold.ready(8)
        assert len(_held_lines(caplog)) == 3 and "second" in _held_lines(caplog)[2]


def test_a_quiet_start_says_only_an_estop(caplog: pytest.LogCaptureFixture) -> None:
    rig = RigWatch(monotonic=lambda: 0)
    hold = SessionHold(rig)
    with caplog.at_level(logging.WARNING, logger="nod.experiment"):
        assert not hold.ready(0, quiet=True)
        assert _held_lines(caplog) == []
        rig.estop(True, "bump", "lab", 1)
        assert not hold.ready(2, quiet=True)
        assert len(_held_lines(caplog)) == 1 and "e-stop engaged" in _held_lines(caplog)[0]


def test_no_trial_starts_while_a_service_it_needs_is_down(caplog: pytest.LogCaptureFixture
                                                           ) -> None:
    # The devices safe and settled, but the decision service killed and not yet back: held,
    # said once; back again, the session goes on.
    clock = [0]
    rig = RigWatch(monotonic=lambda: clock[0])
    hold = SessionHold(rig)
    for device in ("actuation", "eyes"):
        rig.device_state(device, False, "", 0)
    clock[0] = rig.settle_ns
    for device in ("actuation", "eyes"):
        rig.device_state(device, False, "", clock[0])
    assert hold.ready(clock[0])
    with caplog.at_level(logging.WARNING, logger="nod.experiment"):
        assert not hold.ready(clock[0], down=["decision"])
        assert not hold.ready(clock[0], down=["decision"])
        assert _held_lines(caplog) == ["session held: decision not running (restarting?)"]
    assert hold.ready(clock[0])
