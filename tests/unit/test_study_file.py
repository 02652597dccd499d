"""The study file: made from the protocol, written as TOML and read back unchanged; a file that does
not hold together is refused in one line naming the entry (services/study/studyfile.py)."""

from __future__ import annotations

import dataclasses
import re
import tomllib
from pathlib import Path

import pytest

from services.core.config import load_params
from services.model.counterbalance import position_counts
from services.model.protocol import default_schedule
from services.model.schedule import OptionsSchedule
from services.study.studyfile import StudyError, dump, load, make_study, write
from tests.protocols import TWO_TRIALS
from tests.refusals import refused_in_one_line

SHORT = TWO_TRIALS  # a control trial and a consensus one


# option count: (the protocol, its O order, participants in 4 full blocks)
PROTOCOLS = {
    2: (default_schedule(), ["blue", "red", "red", "blue", "red"], 40),
    3: (OptionsSchedule.default(3), ["red", "blue", "green", "red", "blue"], 60),
}


@pytest.mark.parametrize("n", sorted(PROTOCOLS), ids=lambda n: f"{n} options")
def test_round_trip_of_a_study_of_four_blocks(tmp_path, n):
    protocol, base, people = PROTOCOLS[n]
    study = make_study("gaze consensus \"2025\"", protocol, people, seed=11)
    path = tmp_path / "study.toml"
    write(study, path)
    assert load(path) == study
    assert not list(tmp_path.glob("*.tmp"))
    data = tomllib.loads(path.read_text())
    assert data["conditions"] == {
        "control": [1, 2, 3],
        "consensus": [4, 5, 6, 7, 8],
        "gaze_levels": ["minimal", "low", "moderate", "significant", "extreme"],
    }
    assert data["counterbalance"] == {
        "method": "latin-square",
        "base": base,
        "block": 5 * n,
        "seed": 11,
    }
    # The option set is named in the file only when it is not the paper's (whose file is as ever)
    assert data["study"].get("options") == (None if n == 2 else ["red", "blue", "green"])
    assert study.options == (("red", "blue") if n == 2 else ("red", "blue", "green"))
    assert [p["id"] for p in data["participants"]] == [f"P{k:02d}" for k in range(1, people + 1)]
    assert [p["slot"] for p in data["participants"]] == list(range(1, people + 1))
    # every option O at every consensus trial equally often: 20 times each over 4 blocks
    assert position_counts([e.order for e in study.participants], study.options) == [
        (20,) * n] * 5


def test_params_are_stored_relative_to_the_study_file(tmp_path):
    (tmp_path / "protocols").mkdir()
    params = tmp_path / "protocols" / "short.toml"
    params.write_text(SHORT)
    trials = load_params(params).protocol.trials
    study = make_study("pilot", trials, 3, seed=1, params=params, prefix="S")
    (tmp_path / "studies").mkdir()
    path = tmp_path / "studies" / "pilot.toml"
    write(study, path)
    assert 'params = "../protocols/short.toml"' in path.read_text()
    back = load(path)
    assert back == study and back.params == params.resolve()
    assert [e.id for e in back.participants] == ["S01", "S02", "S03"]
    assert all(len(e.order) == 1 for e in back.participants)


def test_a_declared_list_is_taken_as_written(tmp_path):
    study = make_study("declared", default_schedule(), 2, seed=1)
    text = dump(study, tmp_path / "d.toml")
    text = text.replace('method = "latin-square"', 'method = "declared"')
    text = re.sub(r"order = \[.*\]", 'order = ["red", "red", "red", "red", "red"]', text, count=1)
    (tmp_path / "d.toml").write_text(text)
    back = load(tmp_path / "d.toml")
    assert back.counterbalance.method == "declared"
    assert back.participants[0].order == ("red",) * 5
    assert back.participants[0].letters == "RRRRR"


def _edited(tmp_path: Path, old: str, new: str, count: int = 1) -> Path:
    study = make_study("s", default_schedule(), 4, seed=2)
    path = tmp_path / "s.toml"
    text = dump(study, path)
    assert re.search(old, text), old
    path.write_text(re.sub(old, new, text, count=count))
    return path


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (r'id = "P02"', 'id = "P01"', r"participant 'P01' \(slot 2\): the id is given twice"),
        (r'id = "P03"', 'id = "P 3"', r"participant 'P 3' \(slot 3\): participant id 'P 3' must"),
        (r"slot = 4", "slot = 7", "slots must be 1..4 once each"),
        (r"order = \[.*\]", 'order = ["red"]', "order needs red/blue for each of the 5"),
        (r"order = \[.*\]", 'order = ["red", "red", "red", "red", "red"]',
         'not a Latin-square block of BRRBR: RRRRR .* method = "declared"'),
        (r"block = 10", "block = 8", "block = 8, but 5 consensus trials make blocks of 10"),
        (r'method = "latin-square"', 'method = "random"', "method must be one of"),
        (r"consensus = \[4, 5, 6, 7, 8\]", "consensus = [4, 5, 6, 7, 9]", "number the trials"),
        (r'"extreme"\]', '"furious"]', "gaze_levels needs one of"),
        (r"\[study\]", "[studies]", r"needs a \[study\] table"),
        (r"order = \[.*\]", 'order = "RBBRB"', "order must be a list of strings"),
        (r"seed = 2", 'seed = "two"', "seed must be an integer"),
        (r'name = "s"', 'name = "s"\noptions = ["red", "green"]',
         r"options \['red', 'green'\]: two options are the paper's study"),
        (r'name = "s"', 'name = "s"\noptions = ["red", "blue", "red"]',
         "options must be 2 to 8 distinct names"),
    ],
)
def test_a_broken_study_file_is_one_line_naming_the_entry(tmp_path, old, new, message):
    refused_in_one_line(load, _edited(tmp_path, old, new), StudyError, message)


def test_a_missing_or_garbled_file_says_what_to_do(tmp_path):
    with pytest.raises(StudyError, match="nod study init"):
        load(tmp_path / "nope.toml")
    (tmp_path / "bad.toml").write_text("[study\nname=")
    with pytest.raises(StudyError, match="not a readable TOML study file"):
        load(tmp_path / "bad.toml")


def test_make_study_refuses_what_cannot_be_counterbalanced():
    control_only = tuple(t for t in default_schedule() if t.mode == "dissensus")
    with pytest.raises(StudyError, match="no consensus trial"):
        make_study("s", control_only, 4, seed=1)
    with pytest.raises(StudyError, match="--participants"):
        make_study("s", default_schedule(), 0, seed=1)
    with pytest.raises(StudyError, match="participant id"):
        make_study("s", default_schedule(), 2, seed=1, prefix="P/")
    study = make_study("s", default_schedule(), 100, seed=1)
    assert study.participants[0].id == "P001" and study.participants[-1].id == "P100"
    assert dataclasses.replace(study.participants[0]).slot == 1
