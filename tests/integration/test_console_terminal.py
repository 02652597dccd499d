"""The operator's live panel in a real terminal (tmux): the click prompt is drawn inside it.

tmux runs a small script that shows a session's panel and asks for the counter clicks as the
conductor does (`ask_clicks` through the console's prompt); the test types as an operator
would (`send-keys`) and reads the screen (`capture-pane`). Skipped where tmux is missing.
"""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
import textwrap

import pytest

from .conftest import ROOT, wait_for

pytestmark = [
    pytest.mark.integration,
    pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed"),
]

SCRIPT = textwrap.dedent("""
    import logging, termios, threading
    from services.experiment.console import LiveConsole
    from services.experiment.service import ask_clicks

    c = LiveConsole()
    c.start("s1", "P01", 8)
    c.result(1, "dissensus", None, "blue", "red", "D", 0, False)
    c.result(2, "consensus", "red", "red", "red", "C", 2, False)
    c.cue("go", 3, "consensus", "blue")
    # A warning from another thread while the operator types goes into the panel.
    threading.Timer(0.5, logging.getLogger("nod.experiment").warning, ["late warning"]).start()
    first = ask_clicks(3, c.read_line)
    try:
        ask_clicks(4, c.read_line)
        second = "answered"
    except KeyboardInterrupt:
        second = "interrupted"
    c.stop()
    echo = bool(termios.tcgetattr(0)[3] & termios.ECHO)
    print(f"ANSWER {first} {second} echo={echo}")
""")


class Terminal:
    """One tmux server of the test's own (its socket in tmp_path), 100 x 40."""

    def __init__(self, socket: str) -> None:
        self.socket = socket

    def tmux(self, *args: str) -> str:
        return subprocess.run(["tmux", "-S", self.socket, *args], capture_output=True,
                              text=True, check=True, timeout=10).stdout

    def screen(self) -> str:
        return self.tmux("capture-pane", "-p", "-t", "op")

    def shows(self, text: str, timeout: float, what: str) -> str:
        """The screen once it shows `text` (the test fails with `what` after `timeout`)."""
        def showing() -> str | None:
            screen = self.screen()
            return screen if text in screen else None

        return wait_for(showing, timeout, what, every_s=0.05)

    def keys(self, *keys: str) -> None:
        self.tmux("send-keys", "-t", "op", *keys)


@pytest.fixture
def terminal(tmp_path):
    term = Terminal(str(tmp_path / "tmux.sock"))
    yield term
    subprocess.run(["tmux", "-S", term.socket, "kill-server"], capture_output=True, timeout=10)


def test_the_click_prompt_is_typed_inside_the_live_panel(terminal, tmp_path):
    script = tmp_path / "panel.py"
    script.write_text(SCRIPT)
    run = f"cd {shlex.quote(ROOT)} && {shlex.quote(sys.executable)} {shlex.quote(str(script))}"
    terminal.tmux("new-session", "-d", "-s", "op", "-x", "100", "-y", "40",
                  f"{run}; sleep 60")
    terminal.shows("trial 3: counter clicks", 30, "the prompt in the panel")
    terminal.keys("1x")
    terminal.shows("? 1x", 5, "the keys typed, drawn in the panel")
    terminal.keys("BSpace", "Left", "2")  # an edit, and an arrow key that is no answer
    screen = terminal.shows("? 12", 5, "the answer edited")
    prompt = next(line for line in screen.splitlines() if "counter clicks" in line)
    assert prompt.startswith("│") and prompt.rstrip().endswith("│")  # a line of the panel
    terminal.shows("late warning", 5, "the warning in the panel")
    terminal.keys("Enter")
    terminal.shows("trial 4: counter clicks", 5, "the next prompt")
    terminal.keys("C-c")  # Ctrl-C while asked: the prompt gives up, the terminal is restored
    screen = terminal.shows("ANSWER", 10, "the script's end")
    assert "ANSWER 12 interrupted echo=True" in screen
    # One panel on the screen, no copy left behind by the prompt, nothing typed outside it.
    assert screen.count("╭─ session s1") == 1, screen
    assert "counter clicks" not in screen and "late warning" in screen
    assert all(line.startswith(("│", "╭", "╰", "ANSWER")) or not line.strip()
               for line in screen.splitlines()), screen
