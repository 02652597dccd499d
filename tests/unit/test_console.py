"""The operator's console: what it shows for a session's events (rendered, not mocked)."""

from __future__ import annotations

import io
import logging

import pytest
from rich.console import Console

from services.experiment.console import LineConsole, LiveConsole, SessionConsole, make_console


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
        assert c.ask(lambda: 10) == 10  # the prompt runs with the panel stopped, then resumes
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
