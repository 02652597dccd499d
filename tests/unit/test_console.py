"""The operator's console: what it shows for a session's events (rendered, not mocked)."""

from __future__ import annotations

import contextlib
import io
import logging
import os
import sys
import threading
import time

import pytest
from rich.console import Console

from services.experiment.console import LineConsole, LiveConsole, SessionConsole, make_console
from services.experiment.service import ask_clicks
from tests.polling import wait_for


def shown(console: LiveConsole) -> str:
    out = io.StringIO()
    Console(file=out, width=100, color_system=None).print(console.render())
    return out.getvalue()


def test_the_panel_shows_the_trial_the_values_and_the_results() -> None:
    c = LiveConsole()
    c.session, c.participant, c.n = "abc123", "P07", 8
    c.cue("setup", 4, "consensus", "blue", "minimal")
    c.cue("countdown", 4, "consensus", "blue", "2")
    text = shown(c)
    assert "trial 4/8" in text and "O = blue" in text and "countdown 2" in text
    c.cue("go", 4, "consensus", "blue")
    c.value("z_r", -0.8)
    c.value("z_h", 6.5)
    c.value("b_r", -3.25)
    c.robot("move", "blue")
    text = shown(c)
    assert "GO" in text and "-0.800" in text and "+6.500" in text and "-3.250" in text
    assert "robot: move → blue" in text and "human heading: red" in text
    c.result(4, "consensus", "blue", "blue", "blue", "C", 2, False)
    c.result(5, "consensus", "red", None, None, None, 0, True)
    c.note("trial 5 interrupted: actuation lost", "warning")
    text = shown(c)
    assert "score 2" in text and "interrupted" in text and "actuation lost" in text
    # A new trial clears the live values of the last one.
    c.cue("setup", 6, "consensus", "red")
    assert "-3.250" not in shown(c)


def test_warnings_go_into_the_panel_while_it_runs() -> None:
    c = LiveConsole()
    c.console = Console(file=io.StringIO(), width=100)
    c.start("s", "P01", 8)
    try:
        assert c._handler in logging.getLogger().handlers
        logging.getLogger("nod.experiment").warning("session held: %s", "eyes: gaze stale")
        logging.getLogger("nod.experiment").info("not an event")
        assert ("warning", "session held: eyes: gaze stale") in c.events
        assert all("not an event" not in t for _, t in c.events)
    finally:
        c.stop()
    assert c._handler not in logging.getLogger().handlers


def test_lines_for_a_pipe() -> None:
    out = io.StringIO()
    c = LineConsole(out)
    c.start("s1", "P02", 8)
    c.cue("setup", 1, "dissensus", None, "neutral")
    c.cue("go", 1, "dissensus", None)
    c.result(1, "dissensus", None, "blue", "red", "D", 0, False)
    c.note("rig safe again")
    lines = out.getvalue().splitlines()
    assert lines == [
        "session s1 · participant P02 · 8 trials",
        "trial 1/8 [dissensus] gaze set neutral",
        "trial 1/8 [dissensus] GO",
        "trial 1: robot blue, human red → outcome D, score 0",
        "INFO: rig safe again",
    ]


def test_make_console() -> None:
    assert type(make_console("off")) is SessionConsole
    assert isinstance(make_console("lines"), LineConsole)
    assert isinstance(make_console("auto"), LineConsole)  # pytest's stdout is not a terminal
    with pytest.raises(ValueError, match="auto, live, lines or off"):
        make_console("fancy")


@pytest.fixture
def stdin_pipe(monkeypatch):
    """Standard input from a pipe: write the operator's keys to the returned fd."""
    r, w = os.pipe()
    reader = os.fdopen(r, "r")
    monkeypatch.setattr(sys, "stdin", reader)
    yield w
    reader.close()
    with contextlib.suppress(OSError):  # the test closed it (end of input)
        os.close(w)


def test_a_line_prompt_asks_on_the_terminal_and_reads_one_line(stdin_pipe, capsys) -> None:
    os.write(stdin_pipe, b"x7\n12\n\n3")
    c = LineConsole()
    # A wrong answer is asked again (the question says why); each prompt takes one line only.
    assert ask_clicks(4, c.read_line) == 12
    assert ask_clicks(5, c.read_line) is None  # an empty line: not entered
    os.close(stdin_pipe)
    assert ask_clicks(6, c.read_line) == 3  # the last line, without its newline
    assert ask_clicks(7, c.read_line) is None  # the end of input
    out = capsys.readouterr().out
    assert "trial 4: counter clicks — the number the participant counted (target 10; Enter " \
        "alone = not entered)? " in out
    assert "'x7' is not a whole number ≥ 0 — trial 4: counter clicks? " in out


def test_a_waiting_prompt_gives_up_when_the_process_must_stop(stdin_pipe) -> None:
    c = SessionConsole()
    c.interrupt = threading.Event()
    threading.Timer(0.2, c.interrupt.set).start()
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        c.read_line("? ")
    assert time.monotonic() - t0 < 2.0


def test_the_live_prompt_is_a_line_of_the_panel(stdin_pipe) -> None:
    c = LiveConsole()
    c.console = Console(file=io.StringIO(), width=100)
    c.start("s", "P01", 8)
    answer: list[int | None] = []
    try:
        asking = threading.Thread(target=lambda: answer.append(ask_clicks(3, c.read_line)))
        asking.start()
        wait_for(lambda: "trial 3: counter clicks" in shown(c), 5, "the question in the panel")
        os.write(stdin_pipe, b"9\n")
        asking.join(5)
    finally:
        c.stop()
    assert answer == [9]
    assert "counter clicks" not in shown(c)  # answered: the panel no longer asks


def test_the_score_counts_every_trial_and_the_table_shows_the_last_8() -> None:
    c = LiveConsole()
    c.session, c.participant, c.n = "abc", "P03", 10
    for trial in range(1, 11):
        c.result(trial, "consensus", "red", "red", "red", "C", 1, False)
    text = shown(c)
    assert "score 10" in text
    rows = [line.strip("│ ").split()[0] for line in text.splitlines() if "consensus" in line]
    assert rows == [str(t) for t in range(3, 11)]
