"""`nod replay --through decision --policy P`: a robot policy's counterfactual on a recording.

On the golden recorded session (tests/golden/session.mcap: 3 trials, the last two consensus,
recorded by `nod run --sim --record`): the paper's policy writes today's derived file, another
b* changes z_r and b_r in the consensus trials exactly as that b* given in the parameters
does, the policy's gaze is stated as not applied, and a bad policy file is one line.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from services.cohort.policy_file import read_policy_file
from services.core import messages as m
from services.core.keys import topic_of
from services.recording import replay
from services.recording.counterfactual import replay_policy
from services.recording.mcap_io import FILE_METADATA, McapIn, McapOut
from services.recording.through import DECISION_TOPICS, through_decision

GOLDEN = Path(__file__).resolve().parents[1] / "golden" / "session.mcap"

# One candidate: b* 6.0 and the extreme gaze in every consensus trial (a tiny table: the rule
# has a single choice, so the table's size does not matter).
B6 = """\
kind = "adaptive"
gaze_levels = ["extreme"]
b_stars = [6.0]
u_rs = [2.24]
table_people = 3
table_seed = 900000001
"""


@pytest.fixture
def b6(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The one-candidate policy file, its table cached under tmp_path."""
    monkeypatch.setenv("NOD_POLICY_CACHE", str(tmp_path / "tables"))
    path = tmp_path / "b6.toml"
    path.write_text(B6)
    return path


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    return [(e.key, e.message.log_time, e.message.data) for e in McapIn(path)]


def _decision(path: Path) -> dict[tuple[str, int], float]:
    """Every decision output of a file by (topic, the pose it answers)."""
    out = {}
    for e in McapIn(path):
        topic = topic_of(e.key)
        if topic in DECISION_TOPICS:
            msg = m.decode(m.Observed if topic == "decision/z_h" else m.Opinions, e.payload)
            out[(topic, msg.src_seq)] = msg.signed
    return out


def test_the_paper_policy_writes_the_file_through_decision_writes_without_one(tmp_path):
    today, paper = tmp_path / "today.mcap", tmp_path / "paper.mcap"
    res = through_decision(GOLDEN, today, None)
    rep = replay_policy(GOLDEN, paper, None, "paper")
    assert _messages(paper) == _messages(today)  # message for message, byte for byte
    assert [t.line() for t in rep.through.trials] == [t.line() for t in res.trials]
    meta = McapIn(paper).file_metadata()
    assert meta["through_policy"] == "paper"
    assert meta["through_policy_sha256"] == read_policy_file("paper").sha256
    # the paper's robot replayed on the person's motion decides what the live robot did
    assert [(t.settings, t.robot, t.outcome) for t in rep.trials] == [
        (t.paper, t.recorded_robot, t.recorded_outcome) for t in rep.trials]
    assert [t.z_r_at_press for t in rep.trials] == [t.recorded_z_r_at_press for t in rep.trials]


def test_a_policy_with_another_b_star_changes_z_r_and_b_r_as_that_b_star_does(tmp_path, b6):
    today, policy, params = (tmp_path / f"{n}.mcap" for n in ("today", "policy", "params"))
    b6_everywhere = tmp_path / "b6-params.toml"
    b6_everywhere.write_text("[decision.bias]\nb_star = 6.0\n")
    through_decision(GOLDEN, today, None)
    through_decision(GOLDEN, params, b6_everywhere)
    rep = replay_policy(GOLDEN, policy, None, str(b6))

    assert [(t.trial, t.mode, t.settings.b_star) for t in rep.trials] == [
        (1, "dissensus", 4.54), (2, "consensus", 6.0), (3, "consensus", 6.0)]
    base, got, want = _decision(today), _decision(policy), _decision(params)
    assert got.keys() == base.keys() == want.keys()
    # the control trial keeps the paper's b* (b_r is 0 there whatever b*): the file's values
    # are those of b* = 6.0 given for the whole session, and they differ from today's
    assert got == want
    changed = {k for k in base if base[k] != got[k]}
    assert {t for t, _ in changed} == {"decision/z_r", "decision/b_r"}
    assert len(changed) > 100
    for t in rep.trials[1:]:
        assert t.z_r_at_press is not None and t.recorded_z_r_at_press is not None
        assert abs(t.z_r_at_press) > abs(t.recorded_z_r_at_press)  # a higher b* biases more

    meta = McapIn(policy).file_metadata()
    assert meta["through_policy"] == "b6"
    assert meta["through_policy_sha256"] == hashlib.sha256(b6.read_bytes()).hexdigest()
    assert json.loads(meta["through_policy_settings"])["2"] == {
        "b_star": 6.0, "u_r": 2.24, "gaze_level": "extreme"}


def test_the_policys_gaze_is_reported_and_said_not_applied(tmp_path, b6, capsys):
    out = tmp_path / "out.mcap"
    argv = [str(GOLDEN), "--through", "decision", "--policy", str(b6), "--out", str(out)]
    assert replay.main(argv) == 0
    text = capsys.readouterr().out
    assert "NOT applied: the recorded person saw the recorded gaze" in text
    assert ("policy trial 2 consensus O=red: b* 6.00 u_r 2.24 gaze extreme (not applied; "
            "shown: low)") in text

    assert replay.main([*argv, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["counterfactual"] is True and doc["gaze_applied"] is False
    assert doc["policy"] == {"name": "b6", "kind": "adaptive",
                             "sha256": hashlib.sha256(b6.read_bytes()).hexdigest()}
    trial2 = doc["trials"][1]
    assert trial2["policy"]["gaze_level"] == "extreme" and trial2["policy"]["gaze_applied"] is False
    assert trial2["gaze_recorded"] == "low" and trial2["paper"]["gaze_level"] == "low"
    assert set(trial2["would"]) == {"robot", "human", "outcome", "z_r_at_press"}
    assert trial2["recorded"]["outcome"] == "C"
    assert McapIn(out).file_metadata()["through_policy_gaze"].startswith("not applied")


@pytest.mark.parametrize("text, says", [
    ('kind = "nope"\n', "needs kind = \"paper\" or \"adaptive\""),
    ("kind = \n", "not TOML"),
    ('kind = "adaptive"\nb_stars = [6.0]\n', "an adaptive policy needs"),
    ('kind = "adaptive"\ngaze_levels = ["extreme"]\nb_stars = [9.0]\nu_rs = [2.24]\n'
     'table_people = 3\ntable_seed = 1\n', "outside the params file's [policy] envelope"),
])
def test_a_bad_policy_file_is_one_line_and_writes_nothing(tmp_path, capsys, text, says):
    bad, out = tmp_path / "bad.toml", tmp_path / "out.mcap"
    bad.write_text(text)
    code = replay.main([str(GOLDEN), "--through", "decision", "--policy", str(bad), "--out",
                        str(out)])
    err = capsys.readouterr().err
    assert code == 2 and not out.exists()
    (line,) = err.strip().splitlines()
    assert line.startswith("nod replay: ") and says in line


def test_policy_flags_go_with_through_decision(tmp_path, capsys):
    assert replay.main([str(GOLDEN), "--policy", "paper"]) == 2
    assert "go with --through" in capsys.readouterr().err
    code = replay.main([str(GOLDEN), "--through", "decision", "--json", "--out",
                        str(tmp_path / "o.mcap")])
    assert code == 2 and "go with --policy" in capsys.readouterr().err
    code = replay.main([str(GOLDEN), "--through", "decision", "--policy", str(tmp_path / "no"),
                        "--out", str(tmp_path / "o.mcap")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "No such file" in err


def test_a_recording_whose_trials_are_not_its_protocols_is_refused_in_one_line(tmp_path,
                                                                              capsys):
    other = tmp_path / "other.toml"  # trial 2's O blue, where the recorded session had red
    other.write_text("\n".join([
        "[[protocol.trials]]", "index = 1", 'mode = "dissensus"',
        "[[protocol.trials]]", "index = 2", 'mode = "consensus"', 'option = "blue"',
        'gaze_level = "low"',
        "[[protocol.trials]]", "index = 3", 'mode = "consensus"', 'option = "blue"',
        'gaze_level = "significant"', ""]))
    out = tmp_path / "out.mcap"
    code = replay.main([str(GOLDEN), "--through", "decision", "--policy", "paper", "--params",
                        str(other), "--out", str(out)])
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not out.exists()
    assert "trial 2 was recorded as consensus O=red" in line and "consensus O=blue" in line


def test_a_recording_of_three_options_is_refused_as_through_decision_refuses_it(tmp_path):
    src = tmp_path / "three.mcap"
    out = McapOut(src)
    out.metadata(FILE_METADATA, {"rig": "rig1"})
    for i, phase in enumerate(("setup", "go")):
        ev = m.TrialEvent(seq=i, t_ns=5 + i, phase=phase, trial=1, mode="consensus",
                          option="green", options=("red", "blue", "green"))
        out.write_message("nod/rig1/experiment/trial", ev, i)
    pose = m.HandPose(seq=0, t_ns=10, detected=True, center=(0.5, 0.8),
                      landmarks=((0.5, 0.8), (0.51, 0.8)))
    out.write_message("nod/rig1/vision/hand", pose, 3)
    out.finish()
    with pytest.raises(ValueError, match="table of N options .*two-option engine only"):
        replay_policy(src, tmp_path / "out.mcap", None, "paper")
    assert not (tmp_path / "out.mcap").exists()
