"""`nod analyze study` over any option set: three options, and a store of several sets."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from services.analysis.study import load_study, option_shares
from services.store import Store, StoreError, TrialRecord

NAMES = ("red", "blue", "green")
# (human, robot) per trial; O of trials 4-8 is k mod 3: 0, 1, 2, 0, 1
SESSIONS = {
    "P01": [(0, 1), (1, 2), (2, 1), (0, 0), (1, 1), (2, 2), (0, 0), (1, 1)],
    "P02": [(1, 0), (1, 1), (0, 2), (2, 0), (1, 1), (2, 2), (0, 0), (0, 1)],
}


def outcome(h: int, r: int) -> str:
    return "C" if h == r else "D"


def record(trial: int, human: int, robot: int, names: tuple[str, ...] = NAMES) -> TrialRecord:
    option = None if trial <= 3 else names[(trial - 4) % len(names)]
    return TrialRecord(trial, "dissensus" if trial <= 3 else "consensus", option,
                       "neutral", 0.0, 0.0, 1, 2, names[human], names[robot],
                       outcome(human, robot), 0, 0, 10, 1, "human pressed")


def write(store: Store, session: str, who: str, rows: list[tuple[int, int]],
          names: tuple[str, ...] = NAMES, complete: bool = True, skip: int = 0) -> None:
    store.begin_session(session, who, "rig1", 1, 0, {}, names)
    for i, (h, r) in enumerate(rows, start=1):
        if i != skip:
            store.write_trial(session, record(i, h, r, names), ())
    store.finish_session(session, 1, "complete" if complete else "aborted")


def test_the_study_counts_outcomes_and_option_shares_per_trial(tmp_path: Path) -> None:
    db = tmp_path / "s.sqlite"
    store = Store(db)
    for k, (who, rows) in enumerate(SESSIONS.items()):
        write(store, f"s{k}", who, rows)
    write(store, "s9", "P03", SESSIONS["P01"][:5], complete=False)
    store.close()
    doc = load_study(str(db))
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


def test_a_store_of_two_option_sets_analyses_the_papers_and_lists_the_others(
    tmp_path: Path,
) -> None:
    db = tmp_path / "s.sqlite"
    with Store(db) as store:
        write(store, "s0", "P01", SESSIONS["P01"])
        write(store, "s1", "P02", [(h % 2, r % 2) for h, r in SESSIONS["P02"]],
              names=("red", "blue"))
    doc = load_study(str(db))
    assert doc["options"] == ["red", "blue"] and list(doc["grid"]) == ["P02"]
    (other,) = doc["excluded"]
    assert other["participant"] == "P01" and other["reason"] == (
        "ran options red, blue, green: --options red,blue,green analyses them")
    doc = load_study(str(db), options=NAMES)
    assert doc["options"] == list(NAMES) and list(doc["grid"]) == ["P01"]


def test_one_option_set_at_a_time_and_no_store_no_study(tmp_path: Path) -> None:
    db = tmp_path / "s.sqlite"
    store = Store(db)
    write(store, "s0", "P01", SESSIONS["P01"])
    write(store, "s1", "P02", SESSIONS["P02"], names=("red", "blue", "yellow"))
    store.close()
    with pytest.raises(ValueError, match="ran 2 option sets .*--options NAMES picks"):
        load_study(str(db))
    assert load_study(str(db), options=("red", "blue", "yellow"))["participants"] == 1
    with pytest.raises(ValueError, match="no such database"):
        load_study(str(tmp_path / "missing.sqlite"))
    assert option_shares(NAMES, [])["4"] == {"n": 0, "human": {"red": 0, "blue": 0, "green": 0,
                                                               "none": 0},
                                             "robot": {"red": 0, "blue": 0, "green": 0},
                                             "both_on_o": 0}


def test_the_figures_are_written_and_mark_the_agreements(tmp_path: Path) -> None:
    from services.analysis.study_figures import draw_option_shares, write_figures
    from services.analysis.study_report import finite_json

    db = tmp_path / "s.sqlite"
    store = Store(db)
    for k, (who, rows) in enumerate(SESSIONS.items()):
        write(store, f"s{k}", who, rows)
    store.close()
    doc = finite_json(load_study(str(db)))
    paths = write_figures(doc, tmp_path / "fig")
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
    write(store, "s9", "P03", SESSIONS["P01"], skip=6)  # complete, trial 6 never stored
    store.close()
    doc = load_study(str(db))
    assert doc["participants"] == 2 and "P03" not in doc["grid"]
    assert [(e["participant"], e["trials_stored"]) for e in doc["excluded"]] == [("P03", 7)]


def test_a_trial_names_options_of_its_session(tmp_path: Path) -> None:
    with Store(tmp_path / "s.sqlite") as store:
        store.begin_session("s0", "P01", "rig1", 1, 0, {}, NAMES)
        with pytest.raises(ValueError, match="human 'yellow' is not one of"):
            store.write_trial("s0", record(4, 1, 1, ("red", "yellow", "green")), ())
        store.begin_session("s1", "P02", "rig1", 1, 0, {})  # the paper's: red, blue
        with pytest.raises(ValueError, match="option 'green' is not one of"):
            store.write_trial("s1", record(6, 0, 0), ())
        with pytest.raises(ValueError, match="two or more distinct names"):
            store.begin_session("s2", "P03", "rig1", 1, 0, {}, ("red", "red"))
        assert store.option_names("s0") == NAMES and store.option_names("s1") == ("red", "blue")
        store.write_trial("s0", record(4, 0, 0), ())
        with pytest.raises(StoreError, match="was interrupted"):
            store.write_trial("s0", replace(record(5, 1, 1), interrupted=True), ())
            store.set_clicks("s0", 5, 3)
        assert store.set_clicks("s0", 4, 10).clicks == 10
