"""The lab's ACL as data: every rig's identities confined to their rig, the lab's to their rights.

The end-to-end refusals, with real TLS sessions, are in tests/integration/test_lab_rigs.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from services.core.rigfile import MONITOR, identity, load_rig
from services.lab.acl import HOSTS, acl, identities, lab_identities
from services.lab.secure import main as secure_main

RIGS = ["rig1", "rig2", "north-room"]


def _rules_of(doc: dict, name: str) -> list[dict]:
    by_id = {r["id"]: r for r in doc["rules"]}
    (policy,) = [p for p in doc["policies"] if p["subjects"] == [name]]
    return [by_id[r] for r in policy["rules"]]


def test_every_rig_identity_touches_only_its_own_rigs_keys() -> None:
    ids = lab_identities(list(HOSTS), RIGS)
    doc = acl(ids)
    rig_ids = [i for i in ids if not i.name.startswith("lab.")]
    assert len(rig_ids) == len(RIGS) * (2 * len(HOSTS) + 1)
    for ident in rig_ids:
        (rig,) = ident.rigs
        assert ident.name.startswith(f"{rig}.") and ident.folder.startswith(f"{rig}/")
        for rule in _rules_of(doc, ident.name):
            if rule["id"] == "interest":  # who subscribes where: declarations only, outbound
                assert rule["flows"] == ["egress"] and "put" not in rule["messages"]
                continue
            outside = [k for k in rule["key_exprs"] if not k.startswith(f"nod/{rig}/")]
            assert not outside, (ident.name, rule["id"], outside)
    names = [s["id"] for s in doc["subjects"]]
    assert len(names) == len(set(names))  # no certificate name serves two identities


def test_the_lab_estop_engages_and_releases_every_rig_and_the_lab_monitor_reads_it() -> None:
    doc = acl(lab_identities(list(HOSTS), RIGS))

    def puts(name: str) -> set[str]:
        return {
            k
            for r in _rules_of(doc, name)
            if "put" in r["messages"] and r["flows"] == ["ingress"]
            for k in r["key_exprs"]
        }

    assert puts("lab.estop") == {"nod/*/safety/estop", "nod/*/safety/release"}
    assert puts("lab.monitor") == {"nod/*/rig/status"}  # its heartbeat, nothing else
    # A rig's control station releases its own rig only; its other hosts only engage.
    assert {"nod/rig1/safety/estop", "nod/rig1/safety/release"} <= puts("rig1.control")
    assert "nod/rig2/safety/release" not in puts("rig1.control")
    assert "nod/rig1/safety/release" not in puts("rig1.camera")
    assert "nod/rig1/safety/estop" in puts("rig1.camera")


def test_a_single_rig_keeps_its_bare_names() -> None:
    names = [i.name for i in identities(["control", "arm"], "rig7")]
    assert names == ["control", "control-launcher", "arm", "arm-launcher", "monitor"]
    doc = acl(identities(["control", "arm"], "rig7"))
    keys = {k for r in doc["rules"] if r["id"] != "interest" for k in r["key_exprs"]}
    assert all(k.startswith("nod/rig7/") for k in keys), keys


def test_secure_rigs_writes_a_folder_per_rig_the_labs_own_and_the_router(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "lab"
    assert (
        secure_main(
            [
                "--out",
                str(out),
                "--rigs",
                "rig1,rig2",
                "--hosts",
                "control,arm",
                "--router-host",
                "127.0.0.1",
                "--port",
                "7600",
            ]
        )
        == 0
    )
    for folder in ("rig1/control", "rig1/arm/launcher", "rig2/monitor", "lab/monitor", "lab/estop"):
        assert (out / folder / "zenoh.json5").is_file(), folder
        assert (out / folder / "key.pem").stat().st_mode & 0o077 == 0
    assert not (out / "rig1" / "camera").exists()
    router = out / "router" / "router.json5"
    text = router.read_text()
    doc = json.loads(text[text.index("{") :])
    assert doc["listen"]["endpoints"] == ["tls/127.0.0.1:7600"]
    assert {"rig1.control", "rig2.arm-launcher", "lab.estop"} <= {
        s["id"] for s in doc["access_control"]["subjects"]
    }
    assert not (out / "rig1" / "control" / "router.json5").exists()
    # A rig file of rig2 with rig.tls = lab/rig2 finds its identities where `nod up` looks.
    rig = tmp_path / "rig2.toml"
    rig.write_text(
        '[rig]\nname = "rig2"\nrouter = "tls/127.0.0.1:7600"\ntls = "lab/rig2"\n'
        '[hosts.control]\nrouter = false\nservices = ["monitor"]\n'
    )
    assert identity(load_rig(rig), MONITOR).is_file()
    assert "nod router --config" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--rigs", "rig1,lab"], "may not be called 'lab'"),
        (["--rigs", "rig1,router"], "may not be called"),
        (["--rigs", "rig1,rig1"], "distinct"),
        (["--rigs", ","], "distinct"),
        (["--rigs", "rig1,bad rig"], "must be 1-64 letters"),
        (["--rigs", "rig1,rig2", "--rig", "rig1"], "leave out --rig"),
    ],
)
def test_bad_rigs_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], says: str
) -> None:
    assert secure_main(["--out", str(tmp_path / "x"), *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err, err
    assert not (tmp_path / "x").exists()


def test_the_control_station_runs_the_participants_speaker_and_screen_and_the_lsl_outlet() -> None:
    doc = acl(identities(["control", "arm"], "rig1"))
    rules = _rules_of(doc, "control")
    tokens = {k for r in rules if "liveliness_token" in r["messages"] for k in r["key_exprs"]}
    puts = {
        k
        for r in rules
        if "put" in r["messages"] and r["flows"] == ["ingress"]
        for k in r["key_exprs"]
    }
    assert {f"nod/rig1/alive/{s}" for s in ("speaker", "display", "lsl")} <= tokens
    assert {"nod/rig1/speaker/played", "nod/rig1/rig/status"} <= puts
    arm = _rules_of(doc, "arm")
    assert "nod/rig1/alive/display" not in {k for r in arm for k in r["key_exprs"]}
