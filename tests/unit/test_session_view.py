"""The launcher's table: one row per trial stored, a trial given up on marked as such."""

from __future__ import annotations

import io

import pytest

from services.core import messages as m
from services.launch.view import SessionView, session_view
from services.model.params import NodConfig
from services.model.schedule import OptionsSchedule

NAMES = ("red", "blue", "green", "yellow")


def _rows(text: str) -> dict[int, str]:
    return {int(line.split()[0]): line for line in text.splitlines() if line.split()[0].isdigit()}


def _results(n_options: int) -> list[m.TrialResult]:
    """A consensus trial on the last option, then an interrupted one on the first.

    One key space for any option count: the results name their options, and the table too.
    """
    names = NAMES[:n_options]
    last = names[-1]
    return [m.TrialResult(seq=0, t_ns=1, options=names, trial=1, mode="consensus", option=last,
                          robot=last, human=last, outcome="C", score=2),
            m.TrialResult(seq=1, t_ns=2, options=names, trial=2, mode="consensus",
                          option=names[0], interrupted=True)]


@pytest.mark.parametrize("n_options", [2, 3, 4])
def test_the_table_names_the_options_and_marks_an_interrupted_trial(n_options: int) -> None:
    out = io.StringIO()
    names = NAMES[:n_options]
    view = SessionView(2, out, names=names)
    for result in _results(n_options):
        view.on_result(result)
    rows = _rows(out.getvalue())
    assert view.total_trials == 2 and sorted(rows) == [1, 2]
    assert rows[2].endswith("interrupted") and rows[2].split()[2:4] == ["red", "-"]
    assert rows[1].split()[2:6] == [names[-1]] * 3 + ["C"]
    assert not rows[1].endswith("interrupted")


def test_the_paper_table_keeps_its_columns() -> None:
    out = io.StringIO()
    view = SessionView(2, out)
    view.on_result(m.TrialResult(seq=0, t_ns=1, options=("red", "blue"), trial=1, robot="red",
                                 human="blue", outcome="D", score=0))
    header, row = out.getvalue().splitlines()
    assert header == "trial mode       O     robot  human  outcome  switch viol score"
    assert row == "    1 dissensus  -     red    blue   D             0    0     0"


def test_the_view_of_a_run_is_of_its_option_set() -> None:
    cfg = NodConfig()
    assert session_view(cfg, None).names == ("red", "blue")
    schedule = OptionsSchedule.default(3)
    view = session_view(cfg, schedule)
    assert view.names == schedule.names and view.n == len(schedule.trials)


@pytest.mark.parametrize("n_options", [2, 3])
def test_an_interrupted_result_survives_the_wire(n_options: int) -> None:
    sent = m.TrialResult(seq=2, t_ns=3, options=NAMES[:n_options], interrupted=True)
    decoded = m.decode(m.TrialResult, m.encode(sent))
    assert decoded.interrupted and decoded == sent


def test_a_trials_robot_policy_settings_end_its_row() -> None:
    out = io.StringIO()
    view = SessionView(2, out)
    view.on_policy(m.PolicyMsg(seq=0, t_ns=1, session="s", trial=1, policy="adaptive",
                               b_star=6.0, gaze_level="extreme", u_r=2.24, frozen=True))
    for result in _results(2):
        view.on_result(result)
    rows = _rows(out.getvalue())
    assert rows[1].endswith("[adaptive: b*=6 u_r=2.24 gaze extreme, frozen]")
    assert "adaptive" not in rows[2]  # a trial without settings: the paper's robot, as before
    view.begin("P02")
    assert view.policy == {}
