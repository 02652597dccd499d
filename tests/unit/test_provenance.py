"""A session's provenance: the digests are of the real bytes, the store keeps each run's, and
report, export, the recording's metadata and analyze study carry it — real files throughout."""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import shutil
from pathlib import Path

import pytest
from mcap.reader import make_reader

from services.analysis import cli as analyze
from services.core.provenance import (
    PROVENANCE_METADATA,
    HostsSeen,
    make_provenance,
    metadata,
    metadata_arg,
    mixed_params,
    sources_digest,
    tree_digest,
)
from services.experiment import report
from services.experiment.export import main as export_main
from services.experiment.recording import recorder_command
from services.model.protocol import default_schedule
from services.recording import record
from services.recording.mcap_io import FILE_METADATA, McapOut
from services.store import Store, TrialRecord
from services.store.provenance import finish_provenance, read_provenance, write_provenance
from services.study.studyfile import StudyError, load, make_study, write

OUTCOMES = ("D", "C", "DH", "CH", "C", "D", "CH", "C")


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _study(tmp_path: Path, extra: str = "") -> Path:
    path = tmp_path / "study.toml"
    write(make_study("pilot", default_schedule(), 4, seed=11), path)
    text = path.read_text()
    path.write_text(text.replace('on_withdrawal = "keep"',
                                 'on_withdrawal = "keep"\n' + extra, 1))
    return path


def test_the_source_digest_is_of_each_files_path_and_bytes_in_a_stable_order(tmp_path):
    tree = tmp_path / "a"
    (tree / "pkg").mkdir(parents=True)
    (tree / "z.py").write_text("z = 1\n")
    (tree / "pkg" / "m.py").write_text("m = 2\n")
    (tree / "notes.txt").write_text("not source")
    first = tree_digest(tree)
    copy = tmp_path / "b"
    shutil.copytree(tree, copy)
    assert tree_digest(copy) == first  # where it lives does not matter
    (copy / "notes.txt").write_text("changed")
    assert tree_digest(copy) == first  # only .py files count
    (copy / "pkg" / "m.py").write_text("m = 3\n")
    assert tree_digest(copy) != first
    (copy / "pkg" / "m.py").write_text("m = 2\n")
    (copy / "pkg" / "m.py").rename(copy / "pkg" / "n.py")
    assert tree_digest(copy) != first  # a renamed file is another tree
    # the package's own: computed once per process (a tree edited since is not read again)
    digest = sources_digest()
    assert sources_digest() is digest and len(digest) == 64 and int(digest, 16) >= 0


def test_a_runs_provenance_names_every_file_by_its_sha256(tmp_path):
    params, rig = tmp_path / "params.toml", tmp_path / "rig.toml"
    params.write_text("[protocol]\ntarget_clicks = 9\n")
    rig.write_text("# a rig\n")
    study = _study(tmp_path, 'consent_version = "v2 2026-03"\npreregistration = "osf.io/ab12c"')
    p = make_provenance("1.2.3", "0123456789ab", params, rig, None, study)
    assert (p.params_file, p.params_sha256) == (str(params.resolve()), _sha(params))
    assert (p.rig_file, p.rig_sha256) == (str(rig.resolve()), _sha(rig))
    assert p.policy_file is None and p.policy_sha256 is None  # no policy file given
    assert (p.study_name, p.study_sha256, p.consent_version, p.allocation_seed,
            p.preregistration) == ("pilot", _sha(study), "v2 2026-03", 11, "osf.io/ab12c")
    assert (p.version, p.params_hash, p.sources_sha256) == ("1.2.3", "0123456789ab",
                                                            sources_digest())
    loaded = load(study)  # the study file itself reads the new fields too, and writes them back
    assert (loaded.consent_version, loaded.preregistration) == ("v2 2026-03", "osf.io/ab12c")
    write(loaded, tmp_path / "again.toml")
    assert load(tmp_path / "again.toml").preregistration == "osf.io/ab12c"
    bare = make_provenance("1.2.3", "0123456789ab")
    assert bare.params_file is None and bare.study_file is None and bare.consent_version is None
    with pytest.raises(ValueError, match=r"^cannot read the params file .*missing\.toml"):
        make_provenance("1", "h", tmp_path / "missing.toml")
    with pytest.raises(ValueError, match="not a study file"):
        make_provenance("1", "h", study=params)
    _study(tmp_path, "preregistration = 7")
    with pytest.raises(StudyError, match=r"\[study\] preregistration must be a non-empty string"):
        load(tmp_path / "study.toml")


def test_hosts_and_the_mixed_params_line():
    hosts = HostsSeen()
    for service, host in (("decision", "pc"), ("actuation", "pi"), ("decision", "pc"),
                          ("decision", "pc2"), ("eyes", "")):
        hosts.add(service, host)
    assert hosts.hosts() == {"actuation": ("pi",), "decision": ("pc", "pc2")}
    assert mixed_params([("s1", "aaa"), ("s2", "aaa")]) is None
    assert mixed_params([]) is None
    runs = [("s1", "aaa"), ("s2", "bbb"), ("s3", "aaa"), ("s4", "aaa"), ("s5", "aaa")]
    assert mixed_params(runs) == ("sessions ran different parameters: params hash aaa (s1, s3, "
                                  "s4 and 1 more); params hash bbb (s2)")


def _session(store: Store, sid: str, pid: str, k: int) -> None:
    store.begin_session(sid, pid, "rig1", k, 100 * k, {})
    for i in range(1, 9):
        store.write_trial(sid, TrialRecord(
            i, "dissensus" if i <= 3 else "consensus", None if i <= 3 else "red", "neutral",
            0.0, 0.0, 1, 2, "red", "blue", OUTCOMES[(i + k) % 8], 0, 0, 10, 0, "human pressed"),
            ())
    store.finish_session(sid, 100 * k + 50)


def _recording(path: Path, prov_meta: dict[str, str]) -> Path:
    out = McapOut(path)
    out.metadata(FILE_METADATA, {"rig": "rig1"})
    out.metadata(PROVENANCE_METADATA, prov_meta)
    out.finish()
    return path


def test_the_store_keeps_each_run_and_report_and_export_show_it(tmp_path, capsys):
    db = tmp_path / "s.sqlite"
    params = tmp_path / "params.toml"
    params.write_text("# the SPEC defaults\n")
    prov = make_provenance("1.2.3", "0123456789ab", params, study=_study(tmp_path))
    with Store(db) as store:
        _session(store, "s1", "P01", 1)
        write_provenance(store, "s1", 1_000, prov)
        rec = _recording(tmp_path / "s1.mcap", metadata(prov, "s1"))
        assert finish_provenance(store, "s1", 1_000, 2_000, {"decision": ("pc",),
                                                             "experiment": ("ctl",)}, rec) is None
        write_provenance(store, "s1", 3_000, prov)  # resumed: a second run, killed (no finish)
        gone = tmp_path / "gone.mcap"
        assert "no digest of the recording" in (
            finish_provenance(store, "s1", 3_000, 4_000, {}, gone) or "")
        (first, second) = read_provenance(store)
    assert (first.started_ns, first.finished_ns) == (1_000, 2_000)
    assert first.provenance.recording_sha256 == _sha(rec)
    assert first.provenance.hosts == {"decision": ("pc",), "experiment": ("ctl",)}
    assert first.provenance.params_sha256 == _sha(params)
    assert second.provenance.recording_file == str(gone) and second.provenance.recording_sha256 \
        is None

    assert report.main(["--db", str(db), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["session"] == "s1" and [t["trial"] for t in doc["trials"]] == list(range(1, 9))
    assert [r["started_ns"] for r in doc["provenance"]] == [1_000, 3_000]
    assert doc["provenance"][0]["recording_sha256"] == _sha(rec)
    assert doc["provenance"][0]["allocation_seed"] == 11
    assert report.main(["--db", str(db)]) == 0
    text = capsys.readouterr().out
    assert f"params     hash 0123456789ab: {params.resolve()} (sha256 {_sha(params)[:12]})" in text
    assert "hosts      decision on pc; experiment on ctl" in text
    assert f"recording  {rec.resolve()} (sha256 {_sha(rec)[:12]})" in text
    assert "study      pilot:" in text and "allocation seed 11" in text

    out = tmp_path / "csv"
    assert export_main(["--db", str(db), "--out", str(out)]) == 0
    with (out / "provenance.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["session"], r["participant"], r["started_ns"]) for r in rows] == [
        ("s1", "P01", "1000"), ("s1", "P01", "3000")]
    assert rows[0]["recording_sha256"] == _sha(rec) and rows[1]["recording_sha256"] == "NA"
    assert json.loads(rows[0]["hosts"]) == {"decision": ["pc"], "experiment": ["ctl"]}
    assert rows[0]["sources_sha256"] == sources_digest()


def test_a_session_without_provenance_says_so(tmp_path, capsys):
    db = tmp_path / "s.sqlite"
    with Store(db) as store:
        _session(store, "old", "P01", 1)
    assert report.main(["--db", str(db)]) == 0
    assert "provenance: not recorded" in capsys.readouterr().out
    assert report.main(["--db", str(db), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["provenance"] == []


def test_the_recording_carries_the_provenance_as_a_metadata_record(tmp_path, monkeypatch):
    prov = make_provenance("1.2.3", "0123456789ab", study=_study(tmp_path))
    meta = metadata(prov, "s9")
    args = argparse.Namespace(rig="rig1", mode="peer", connect=None, config=None, params=None,
                              participant="P01", speed=1.0, epoch_ns=None)
    cmd = recorder_command(args, tmp_path / "s9.mcap", "s9", meta)
    given = cmd[cmd.index("--provenance") + 1]
    assert metadata_arg(given) == meta
    with pytest.raises(argparse.ArgumentTypeError, match="a JSON object of strings"):
        metadata_arg('{"a": 1}')

    class NoTraffic:  # the recorder's tap on a rig where nobody publishes
        dropped = 0

        def __init__(self, *_a: object, **_k: object) -> None:
            pass

        def next(self, _until: float) -> None:
            return None

        def close(self) -> None:
            pass

    monkeypatch.setattr(record, "Tap", NoTraffic)
    monkeypatch.setattr(record, "install_signal_handlers", lambda *a, **k: None)
    path = tmp_path / "s9.mcap"
    rargs = record.build_parser().parse_args(["--out", str(path), "--duration", "0.01",
                                              "--provenance", given])
    out = McapOut(path)
    assert record._record(rargs, None, out, ["nod/rig1/**"], {"rig": "rig1"}) == 0  # type: ignore[arg-type]
    with path.open("rb") as fh:
        found = {md.name: md.metadata for md in make_reader(fh).iter_metadata()}
    assert found[PROVENANCE_METADATA] == meta
    assert meta["session"] == "s9" and meta["study_name"] == "pilot"
    assert meta["sources_sha256"] == sources_digest() and "recording_sha256" not in meta


def test_analyze_study_refuses_sessions_of_other_parameters_unless_told(tmp_path, capsys):
    db = tmp_path / "s.sqlite"
    with Store(db) as store:
        for k in range(1, 5):
            _session(store, f"s{k}", f"P0{k}", k)
            digest = "aaaaaaaaaaaa" if k != 3 else "bbbbbbbbbbbb"
            write_provenance(store, f"s{k}", k, make_provenance("1", digest))
        _session(store, "s5", "P05", 5)  # stored before provenance was kept
    assert analyze.main(["study", "--db", str(db), "--json"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err
    assert err.endswith("sessions ran different parameters: params hash aaaaaaaaaaaa (s1, s2, "
                        "s4); params hash bbbbbbbbbbbb (s3): not pooled (--mixed-params pools "
                        "them anyway)")
    assert analyze.main(["study", "--db", str(db), "--json", "--mixed-params"]) == 0
    captured = capsys.readouterr()
    assert "pooled (--mixed-params)" in captured.err
    doc = json.loads(captured.out)
    assert doc["params"]["by_hash"] == {"aaaaaaaaaaaa": ["s1", "s2", "s4"],
                                        "bbbbbbbbbbbb": ["s3"]}
    assert doc["params"]["unknown"] == ["s5"] and doc["participants"] == 5
