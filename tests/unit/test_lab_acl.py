"""The lab's ACL as data: every rig's identities confined to their rig, the lab's to their rights.

The end-to-end refusals, with real TLS sessions, are in tests/integration/test_lab_rigs.py (one
router) and tests/integration/test_lab_rig_routers.py (a router per rig and a lab router).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import NameOID

from services.core.rigfile import MONITOR, identity, load_rig
from services.lab.acl import (
    HOSTS,
    acl,
    identities,
    lab_identities,
    lab_router_acl,
    rig_router_acl,
)
from services.lab.secure import main as secure_main
from services.launch.preflight import problems
from services.launch.up import router_command

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
    flags = "--rigs rig1,rig2 --hosts control,arm --router-host 127.0.0.1 --port 7600"
    assert secure_main(["--out", str(out), *flags.split()]) == 0
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


def _refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], says: str
) -> None:
    """`nod lab secure ARGS…` exits 2 with one line saying `says`, and writes nothing."""
    assert secure_main(["--out", str(tmp_path / "x"), *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err, err
    assert not (tmp_path / "x").exists()


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
    _refused_in_one_line(tmp_path, capsys, args, says)


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


def _puts(doc: dict, name: str) -> set[str]:
    return {
        k
        for r in _rules_of(doc, name)
        if "put" in r["messages"] and r["flows"] == ["ingress"]
        for k in r["key_exprs"]
    }


def _outside(doc: dict, name: str, rig: str) -> list[tuple[str, str]]:
    """The keys of `name`'s rules outside `rig`, but for the interest rules (no data)."""
    return [
        (r["id"], k)
        for r in _rules_of(doc, name)
        if r["id"] not in ("interest", "observe:every-rig")
        for k in r["key_exprs"]
        if not k.startswith(f"nod/{rig}/")
    ]


def test_a_rig_router_admits_its_rig_the_labs_identities_and_the_lab_router_on_its_rig_only():
    doc = rig_router_acl(list(HOSTS), "rig1")
    names = [s["id"] for s in doc["subjects"]]
    assert {
        "rig1.control",
        "rig1.arm-launcher",
        "rig1.monitor",
        "lab.monitor",
        "lab.estop",
        "lab.router",
    } <= set(names)
    assert not [n for n in names if n.startswith("rig2.")] and len(names) == len(set(names))
    for name in names:
        assert _outside(doc, name, "rig1") == [], name
    # The lab router brings no more than the lab's identities may do on this rig.
    assert (
        _puts(doc, "lab.router")
        == _puts(doc, "lab.estop") | _puts(doc, "lab.monitor")
        == {"nod/rig1/safety/estop", "nod/rig1/safety/release", "nod/rig1/rig/status"}
    )
    every = {r["id"]: r for r in doc["rules"]}["observe:every-rig"]
    assert every["key_exprs"] == ["nod/*/**"] and "put" not in every["messages"]
    assert "observe:every-rig" not in [r["id"] for r in _rules_of(doc, "rig1.control")]


def test_the_lab_router_admits_each_rig_router_for_its_own_rig_and_no_rig_host():
    doc = lab_router_acl(list(HOSTS), RIGS)
    names = {s["id"] for s in doc["subjects"]}
    assert names == {"lab.monitor", "lab.estop", *(f"{r}.router" for r in RIGS)}
    single = acl(lab_identities(list(HOSTS), RIGS))
    for rig in RIGS:
        assert _outside(doc, f"{rig}.router", rig) == []
        # What the rig router may put is what its rig's identities (and the lab's) may there.
        hosts = {
            k
            for n in (s["id"] for s in single["subjects"])
            if n.startswith(f"{rig}.")
            for k in _puts(single, n)
        }
        assert hosts <= _puts(doc, f"{rig}.router") <= hosts | {f"nod/{rig}/rig/status"}
    assert "nod/rig2/safety/release" not in _puts(doc, "rig1.router")
    assert _puts(doc, "lab.estop") == {"nod/*/safety/estop", "nod/*/safety/release"}


def _doc(path: Path) -> dict:
    text = path.read_text()
    return json.loads(text[text.index("{") :])


def test_secure_router_per_rig_writes_each_rigs_router_linked_to_the_lab_router(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "lab"
    rig2 = tmp_path / "rig2.toml"
    rig2.write_text(
        '[rig]\nname = "rig2"\nrouter = "tls/rig2.lab:7448"\ntls = "lab/rig2"\n'
        '[hosts.control]\nrouter = true\nservices = ["monitor"]\n'
    )
    flags = "--rigs rig1,rig2 --hosts control,arm --router-per-rig --router-host router.lab"
    rig_routers = ["--rig-router", "rig1=10.0.1.1:7447", "--rig-router", f"rig2={rig2}"]
    assert secure_main(["--out", str(out), *flags.split(), "--port", "7600", *rig_routers]) == 0
    lab = _doc(out / "router" / "router.json5")
    assert lab["listen"]["endpoints"] == ["tls/router.lab:7600"] and "connect" not in lab
    assert lab["scouting"]["gossip"] == {"enabled": False}
    assert {s["id"] for s in lab["access_control"]["subjects"]} == {
        "lab.monitor",
        "lab.estop",
        "rig1.router",
        "rig2.router",
    }
    for rig, where in (("rig1", "10.0.1.1:7447"), ("rig2", "rig2.lab:7448")):
        router = _doc(out / rig / "router" / "router.json5")
        assert router["listen"]["endpoints"] == [f"tls/{where}"]
        assert router["connect"]["endpoints"] == ["tls/router.lab:7600"]
        tls = router["transport"]["link"]["tls"]
        assert tls["enable_mtls"] and tls["verify_name_on_connect"]
        assert (
            tls["connect_certificate"]
            == tls["listen_certificate"]
            == str((out / rig / "router" / "cert.pem").absolute())
        )
        assert "lab.router" in {s["id"] for s in router["access_control"]["subjects"]}
        cert = x509.load_pem_x509_certificate((out / rig / "router" / "cert.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == (
            f"{rig}.router"
        )
        assert (out / rig / "router" / "key.pem").stat().st_mode & 0o077 == 0
        for who in ("control", "arm/launcher", "monitor"):  # the rig's hosts: their router
            client = _doc(out / rig / who / "zenoh.json5")
            assert client["connect"]["endpoints"] == [f"tls/{where}"], (rig, who)
    for who in ("monitor", "estop"):  # the lab's identities: the lab router
        client = _doc(out / "lab" / who / "zenoh.json5")
        assert client["connect"]["endpoints"] == ["tls/router.lab:7600"]
    assert not (out / "rig1" / "camera").exists()
    printed = capsys.readouterr().out
    assert f"{out.absolute()}/rig2/router/router.json5" in printed
    # `nod up` on a rig router's host starts that router, with its config.
    rig = load_rig(rig2)
    assert router_command(rig)[-1] == str(rig.tls / "router" / "router.json5")
    # …and its preflight (`nod up --dry-run`) checks that router's files, not control/'s.
    router_host = next(h for h, host in rig.hosts.items() if host.router)
    found = problems(rig, [], host=router_host, with_router=True, sim_hardware=True)
    assert not any("router" in line for line in found), found
    (rig.tls / "router" / "router.json5").unlink()
    found = problems(rig, [], host=router_host, with_router=True, sim_hardware=True)
    assert any("control/router.json5" in line for line in found), found


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--router-per-rig"], "needs --rigs"),
        (["--rigs", "rig1,rig2", "--rig-router", "rig1=h:1"], "needs --router-per-rig"),
        (["--rigs", "rig1,rig2", "--router-per-rig", "--rig-router", "rig1=h:1"], "missing: rig2"),
        (["--rigs", "rig1", "--router-per-rig", "--rig-router", "rig3=h:1"], "for a rig of --rigs"),
        (["--rigs", "rig1", "--router-per-rig", "--rig-router", "rig1=tcp/h:1"], "TLS only"),
        (
            ["--rigs", "rig1", "--router-per-rig", "--rig-router", "rig1=0.0.0.0:1"],
            "every interface",
        ),
        (["--rigs", "rig1", "--router-per-rig", "--rig-router", "rig1=h"], "not an endpoint"),
        (
            [
                "--rigs",
                "rig1,rig2",
                "--router-per-rig",
                "--rig-router",
                "rig1=h:1",
                "--rig-router",
                "rig2=h:1",
            ],
            "at one address",
        ),
        (
            [
                "--rigs",
                "rig1",
                "--router-per-rig",
                "--rig-router",
                "rig1=h:1",
                "--rig-router",
                "rig1=h:2",
            ],
            "twice",
        ),
        (["--rigs", "rig1", "--router-per-rig", "--rig-router", "rig1=nowhere.toml"], "rig1"),
    ],
)
def test_bad_router_per_rig_flags_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], says: str
) -> None:
    _refused_in_one_line(tmp_path, capsys, args, says)


def test_a_rig_file_of_another_rig_or_the_lab_routers_rig_file_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    other = tmp_path / "rig7.toml"
    other.write_text(
        '[rig]\nname = "rig7"\nrouter = "tls/h:7447"\n'
        '[hosts.control]\nrouter = true\nservices = ["monitor"]\n'
    )
    base = ["--out", str(tmp_path / "x"), "--rigs", "rig1,rig7", "--router-per-rig"]
    assert secure_main([*base, "--rig-router", f"rig1={other}", "--rig-router", "rig7=h:1"]) == 2
    assert "is rig 'rig7'" in capsys.readouterr().err
    assert secure_main([*base, "--rig-file", str(other)]) == 2
    assert "--rig-file is ambiguous" in capsys.readouterr().err
