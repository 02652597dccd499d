"""The counter clicks: entered after a trial is stored, they change its clicks and points only.

The conductor stores a trial the moment it ends (clicks not entered) and asks after; `nod
clicks` enters or corrects them later. Real store files; the points follow the paper's scoring
(`services.model.scoring`) with the session's own target.
"""

from __future__ import annotations

import dataclasses
import threading
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.experiment import clicks
from services.experiment.operator import EnterStarts, OperatorGate
from services.model.params import NodConfig
from services.model.scoring import points_said, score_trial, trial_points
from services.store import Store, StoreError, TrialRecord


def stored(tmp_path: Path, human="red", robot="red", violations=0, target=10,
           interrupted=False) -> Path:
    path = tmp_path / "s.sqlite"
    store = Store(path)
    cfg = NodConfig()
    cfg = dataclasses.replace(cfg, protocol=dataclasses.replace(cfg.protocol,
                                                                target_clicks=target))
    store.begin_session("s1", "P01", "rig1", 1, 10**12, cfg.summary())
    rec = TrialRecord(3, "consensus", "red", "high", 0.0, 0.0, 10**12, 2 * 10**12, human,
                      robot, "C", 0, violations, None,
                      trial_points(human, robot, violations, None, target), "human pressed",
                      interrupted=interrupted)
    store.write_trial("s1", rec, [])
    store.close()
    return path


def trial(path: Path) -> TrialRecord:
    store = Store(path)
    try:
        return {t.trial: t for _, t in store.trials("s1")}[3]
    finally:
        store.close()


def test_clicks_entered_later_rescore_the_trial_with_the_sessions_target(tmp_path, capsys):
    path = stored(tmp_path, target=12)
    assert trial(path).score == 1 and trial(path).clicks is None  # same buzzer, not entered
    assert clicks.main(["--db", str(path), "--session", "s1", "--trial", "3", "--count", "12"]) == 0
    assert (trial(path).clicks, trial(path).score) == (12, 2)
    assert "clicks not entered → 12; 2 point(s)" in capsys.readouterr().out
    assert clicks.main(["--db", str(path), "--session", "s1", "--trial", "3", "--count", "10"]) == 0
    assert (trial(path).clicks, trial(path).score) == (10, 0)  # 10 ≠ 12: a failed task, −1
    assert clicks.main(["--db", str(path), "--session", "s1", "--trial", "3",
                        "--not-entered"]) == 0
    assert (trial(path).clicks, trial(path).score) == (None, 1)


def test_clicks_of_a_missing_or_interrupted_trial_are_refused_in_one_line(tmp_path, capsys):
    path = stored(tmp_path, interrupted=True)
    assert clicks.main(["--db", str(path), "--session", "s1", "--trial", "3", "--count", "1"]) == 2
    assert "interrupted: never scored" in capsys.readouterr().err
    assert clicks.main(["--db", str(path), "--session", "s1", "--trial", "4", "--count", "1"]) == 2
    assert "no stored trial 4" in capsys.readouterr().err
    assert trial(path).clicks is None
    with pytest.raises(StoreError):
        Store(path).set_clicks("nope", 3, 1)


@given(st.sampled_from(["red", "blue", None]), st.sampled_from(["red", "blue", None]),
       st.integers(0, 3), st.one_of(st.none(), st.integers(0, 30)), st.integers(1, 20))
def test_points_of_a_stored_trial_are_the_judges(human, robot, violations, count, target):
    same = human is not None and human == robot
    assert trial_points(human, robot, violations, count, target) == score_trial(
        same, count, violations, target).total
    said = points_said(human, robot, violations, count, target)
    assert said.startswith(f"{trial_points(human, robot, violations, count, target)} point(s)")


class TypingConsole:
    """A console an operator types at: answers `line` at once, or waits for `cancel`."""

    interactive = True

    def __init__(self, line: str | None) -> None:
        self.line = line
        self.asked: list[str] = []

    def read_line(self, question: str, cancel: threading.Event | None = None) -> str:
        self.asked.append(question)
        if self.line is None:
            assert cancel is not None
            cancel.wait(10)
            raise KeyboardInterrupt
        return self.line


def test_enter_at_the_console_starts_the_waiting_trial():
    gate, lock = OperatorGate(), threading.RLock()
    starts = EnterStarts(TypingConsole(""), gate, lock)
    assert gate.starts_it.startswith("Enter here")
    starts.offer(4)
    starts._asking[2].join(5)  # noqa: SLF001 - the question's thread, answered at once
    assert gate._start == 4  # noqa: SLF001 - the start it set, for trial 4 only


def test_a_trial_started_elsewhere_withdraws_the_question_and_starts_nothing():
    gate, lock = OperatorGate(), threading.RLock()
    console = TypingConsole(None)  # the operator types nothing
    starts = EnterStarts(console, gate, lock)
    starts.offer(4)
    starts.offer(4)  # asked once per waiting trial
    starts.withdraw()  # `nod experiment next` started it
    assert gate._start is None and len(console.asked) == 1  # noqa: SLF001


def test_keys_typed_ahead_on_a_terminal_are_dropped_before_a_question():
    import os
    import pty
    import select

    from services.experiment.console import _drop_typed_ahead

    master, slave = pty.openpty()
    try:
        os.write(master, b"\n\n7\n")  # Enter pressed while nothing was asked
        assert select.select([slave], [], [], 2)[0]
        _drop_typed_ahead(slave)
        assert not select.select([slave], [], [], 0.2)[0]  # nothing left to answer with
        os.write(master, b"9\n")  # what is typed after the question is read
        assert os.read(slave, 10) == b"9\n"
    finally:
        os.close(master)
        os.close(slave)


def test_clicks_of_an_n_option_session_rescore_its_trial(tmp_path, capsys):
    path = tmp_path / "o.sqlite"
    with Store(path) as store:
        store.begin_session("o1", "P01", "rig1", 1, 10**12, NodConfig().summary(),
                            ("red", "blue", "green"))
        store.write_trial("o1", TrialRecord(
            2, "consensus", "green", "low", 0.0, 0.0, 10**12, 2 * 10**12, "green", "green",
            "C", 0, 0, None, trial_points("green", "green", 0, None), "human pressed"), ())
    assert clicks.main(["--db", str(path), "--session", "o1", "--trial", "2", "--count",
                        "10"]) == 0
    with Store(path) as store:
        ((_, rec),) = store.trials("o1")
    assert (rec.clicks, rec.score) == (10, 2)
    assert "2 point(s)" in capsys.readouterr().out
