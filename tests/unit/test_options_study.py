"""The study analysis over sessions of three options, beside the paper's."""

from __future__ import annotations

from pathlib import Path

import pytest

from services.analysis.options_study import analyze_options_study, option_shares
from services.analysis.sessions import select_sessions
from services.store import Store
from services.store.options import OptionsStore, OptionsTrialRecord

NAMES = ("red", "blue", "green")
# (human, robot) per trial; O of trials 4-8 is k mod 3: 0, 1, 2, 0, 1
SESSIONS = {
    "P01": [(0, 1), (1, 2), (2, 1), (0, 0), (1, 1), (2, 2), (0, 0), (1, 1)],
    "P02": [(1, 0), (1, 1), (0, 2), (2, 0), (1, 1), (2, 2), (0, 0), (0, 1)],
}


def outcome(h: int, r: int) -> str:
    return "C" if h == r else "D"


def record(trial: int, human: int, robot: int) -> OptionsTrialRecord:
    option = None if trial <= 3 else (trial - 4) % 3
    return OptionsTrialRecord(trial, "dissensus" if trial <= 3 else "consensus", option,
                              "neutral", 0.0, 0.0, 1, 2, human, robot,
                              outcome(human, robot), 0, 0, 10, 1, "human pressed")


def write(store: Store, session: str, who: str, rows: list[tuple[int, int]],
          names: tuple[str, ...] = NAMES, complete: bool = True) -> None:
    options = OptionsStore(store)
    options.begin_session(session, who, "rig1", 1, 0, {}, names)
    for i, (h, r) in enumerate(rows, start=1):
        options.write_trial(session, record(i, h, r))
    store.finish_session(session, 1, "complete" if complete else "aborted")


def test_the_study_counts_outcomes_and_option_shares_per_trial(tmp_path: Path) -> None:
    db = tmp_path / "s.sqlite"
    store = Store(db)
    for k, (who, rows) in enumerate(SESSIONS.items()):
        write(store, f"s{k}", who, rows)
    write(store, "s9", "P03", SESSIONS["P01"][:5], complete=False)
    store.close()
    doc = analyze_options_study(db)
    assert doc["options"] == list(NAMES) and doc["participants"] == 2
    assert [e["participant"] for e in doc["excluded"]] == ["P03"]
    assert doc["frequencies"]["4"]["C"] == 1 and doc["frequencies"]["4"]["D"] == 1
    shares = doc["option_shares"]
    assert shares["1"]["human"] == {"red": 1, "blue": 1, "green": 0, "none": 0}
    assert shares["1"]["robot_not_human"] == 2
    assert shares["4"]["both_on_o"] == 1  # P01 both on red; P02 human on green
    assert shares["8"]["both_on_o"] == 1 and shares["8"]["robot"] == {"red": 0, "blue": 2,
                                                                       "green": 0}
    assert "p" in doc["stuart_maxwell"]["control_vs_experiment"] or \
        "error" in doc["stuart_maxwell"]["control_vs_experiment"]


def test_the_papers_study_leaves_option_sessions_out(tmp_path: Path) -> None:
    store = Store(tmp_path / "s.sqlite")
    write(store, "s0", "P01", SESSIONS["P01"])
    selection = select_sessions(store)
    store.close()
    assert not selection.participants and not selection.excluded  # not the paper's at all


def test_one_option_set_at_a_time_and_no_store_no_study(tmp_path: Path) -> None:
    db = tmp_path / "s.sqlite"
    store = Store(db)
    write(store, "s0", "P01", SESSIONS["P01"])
    write(store, "s1", "P02", SESSIONS["P02"], names=("red", "blue", "yellow"))
    store.close()
    with pytest.raises(ValueError, match="different option sets"):
        analyze_options_study(db)
    with pytest.raises(ValueError, match="no session database"):
        analyze_options_study(tmp_path / "missing.sqlite")
    assert option_shares(NAMES, [])["4"] == {"n": 0, "human": {"red": 0, "blue": 0, "green": 0,
                                                               "none": 0},
                                             "robot": {"red": 0, "blue": 0, "green": 0},
                                             "both_on_o": 0}


def test_the_figures_are_written_and_mark_the_agreements(tmp_path: Path) -> None:
    from services.analysis.options_figures import draw_option_shares, write_options_figures
    from services.analysis.study_report import finite_json

    db = tmp_path / "s.sqlite"
    store = Store(db)
    for k, (who, rows) in enumerate(SESSIONS.items()):
        write(store, f"s{k}", who, rows)
    store.close()
    doc = finite_json(analyze_options_study(db))
    paths = write_options_figures(doc, tmp_path / "fig")
    assert set(paths) == {"8a", "8b", "8c", "8d", "shares"}
    assert all(p.stat().st_size > 1000 for p in paths.values())
    fig = draw_option_shares(doc)
    labels = [t.get_text() for t in fig.axes[0].texts]
    # control: both robots elsewhere in trial 1; consensus: trial 4 one of two on O, trial 6 both
    assert labels[0] == "2/2" and labels[3] == "1/2" and labels[5] == "2/2"


def test_a_complete_session_missing_a_scheduled_trial_is_excluded(tmp_path: Path) -> None:
    # Inclusion as the paper's study: status complete *and* every scheduled trial stored.
    db = tmp_path / "s.sqlite"
    store = Store(db)
    for k, (who, rows) in enumerate(SESSIONS.items()):
        write(store, f"s{k}", who, rows)
    options = OptionsStore(store)
    options.begin_session("s9", "P03", "rig1", 1, 0, {}, NAMES)
    for trial, (h, r) in enumerate(SESSIONS["P01"], start=1):
        if trial != 6:  # trial 6 never stored
            options.write_trial("s9", record(trial, h, r))
    store.finish_session("s9", 1, "complete")
    store.close()
    doc = analyze_options_study(db)
    assert doc["participants"] == 2 and "P03" not in doc["grid"]
    assert [(e["participant"], e["trials_stored"]) for e in doc["excluded"]] == [("P03", 7)]
