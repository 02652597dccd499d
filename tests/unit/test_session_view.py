"""The launcher's table: one row per trial stored, a trial given up on marked as such."""

from __future__ import annotations

import io

from services.core import messages as m
from services.core import options_messages as om
from services.launch.options_view import OptionsSessionView
from services.launch.view import SessionView


def _rows(text: str) -> dict[int, str]:
    return {int(line.split()[0]): line for line in text.splitlines() if line.split()[0].isdigit()}


def test_the_paper_table_marks_an_interrupted_trial_and_counts_it() -> None:
    out = io.StringIO()
    view = SessionView(2, out)
    view.on_result(m.TrialResult(seq=0, t_ns=1, trial=1, robot="red", human="blue",
                                 outcome="D", score=0))
    view.on_result(m.TrialResult(seq=1, t_ns=2, trial=2, interrupted=True))
    rows = _rows(out.getvalue())
    assert view.total_trials == 2 and sorted(rows) == [1, 2]
    assert rows[2].endswith("interrupted") and not rows[1].endswith("interrupted")
    assert rows[1].split()[3:6] == ["red", "blue", "D"]  # after the mode and O (none)


def test_the_options_table_marks_an_interrupted_trial_and_counts_it() -> None:
    out = io.StringIO()
    view = OptionsSessionView(("red", "blue", "green"), 2, out)
    view.on_options_result(om.OptionsResult(seq=0, t_ns=1, n_options=3, trial=1, mode="consensus",
                                            option=2, robot=2, human=2, outcome="C", score=2))
    view.on_options_result(om.OptionsResult(seq=1, t_ns=2, n_options=3, trial=2,
                                            mode="consensus", option=0, interrupted=True))
    rows = _rows(out.getvalue())
    assert view.total_trials == 2 and sorted(rows) == [1, 2]
    assert rows[2].endswith("interrupted") and rows[2].split()[2:4] == ["red", "-"]
    assert rows[1].split()[2:6] == ["green", "green", "green", "C"]
    assert not rows[1].endswith("interrupted")
    decoded = m.decode(om.OptionsResult, m.encode(om.OptionsResult(seq=2, t_ns=3, n_options=3,
                                                                   interrupted=True)))
    assert decoded.interrupted
