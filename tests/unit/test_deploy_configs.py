"""The deploy folder's Zenoh configs load, and every systemd unit points at a real role."""

import json
import re
from pathlib import Path

import pytest
import zenoh

from services.core.limits import low_pass_filters

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


@pytest.mark.parametrize("name", ["router.json5", "client.json5", "single-host.json5"])
def test_zenoh_configs_parse(name):
    conf = zenoh.Config.from_file(str(DEPLOY / "zenoh" / name))
    assert conf.get_json("mode") in ('"router"', '"client"', "router", "client")
    assert conf.get_json("scouting/multicast/enabled") in ("false", False)
    assert int(conf.get_json("transport/link/rx/max_message_size")) == 1 << 20
    # A stock zenohd with this file bounds every key of the contract as `nod` sessions do, and
    # keeps shared memory off (scripts/sync-zenoh-limits writes the rules from the contract).
    rules = [{k: v for k, v in r.items() if v is not None}
             for r in json.loads(conf.get_json("low_pass_filter"))]
    assert rules == low_pass_filters(), "out of date: run scripts/sync-zenoh-limits"
    assert conf.get_json("transport/shared_memory/enabled") == "false"


def _unit(name: str) -> dict[str, dict[str, str]]:
    """A systemd unit's [Section] key=value pairs (comments dropped)."""
    sections: dict[str, dict[str, str]] = {}
    current = ""
    for line in (DEPLOY / "systemd" / name).read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("["):
            current = line.strip("[]")
            sections[current] = {}
        else:
            key, _, value = line.partition("=")
            sections[current][key] = value
    return sections


@pytest.mark.parametrize("name", ["nod@.service", "nod-router.service"])
def test_systemd_units_run_the_rig_file_as_a_non_root_user(name):
    unit = _unit(name)
    svc = unit["Service"]
    assert svc["User"] == "nod" and svc["Group"] == "nod"
    assert svc["Restart"] == "on-failure"
    assert "/etc/nod/rig.toml --host ${NOD_HOST} --exec" in svc["ExecStart"]
    assert "setup-env" not in svc["ExecStart"] and "pip" not in svc["ExecStart"]  # no install
    assert unit["Unit"]["StartLimitBurst"] == "5"  # a crash loop is left down, not hidden
    assert int(svc["TimeoutStopSec"]) >= 3  # services stop within 2 s of SIGTERM
    if name == "nod@.service":
        assert set(svc["SupplementaryGroups"].split()) == {"dialout", "video"}


def test_the_example_rig_file_plans_every_host():
    from services.core.rigfile import load_rig
    from services.launch.up import plan, router_command

    rig = load_rig(DEPLOY / "rig.example.toml")
    assert set(rig.services) == {"vision", "decision", "actuation", "eyes", "monitor"}
    placed = [s for h in rig.hosts for s in plan(rig, h)[0]]
    assert sorted(placed) == sorted(rig.services)  # every service on exactly one host
    assert [h for h in rig.hosts if plan(rig, h)[1]] == ["control"]
    assert router_command(rig)[-2:] == ["--listen", rig.router]
    assert (DEPLOY / rig.sections["actuation"]["config"].relative_to(DEPLOY)).exists()


def test_launch_script_uses_the_rig_file():
    launch = (DEPLOY / "lab" / "launch").read_text()
    assert 'up "${NOD_RIG_FILE:-/etc/nod/rig.toml}" --host "$host"' in launch
    assert "setup-env\n" not in launch.replace('run $home/scripts/setup-env first', '')


def test_the_env_example_reads_the_same_in_systemd_and_bash():
    """setup-host makes /etc/nod/nod.env from it: a unit's EnvironmentFile= keeps a trailing
    `# …` in the value, so comments stand on lines of their own; it names what the deploy reads."""
    names = set()
    for line in (DEPLOY / "nod.env.example").read_text().splitlines():
        if not line or line.startswith("#"):
            continue
        key, sep, value = line.partition("=")
        assert sep and key.isidentifier() and "#" not in value and value == value.strip(), line
        names.add(key)
    readers = ("lab/launch", "setup-host", "systemd/nod@.service", "systemd/nod-router.service")
    read = "".join((DEPLOY / name).read_text() for name in readers)
    assert set(re.findall(r"\bNOD_[A-Z_]+", read)) - {"NOD_ENV"} <= names  # NOD_ENV: the file
    assert "deploy/nod.env.example" in (DEPLOY / "setup-host").read_text()


def test_example_params_load_and_match_the_defaults():
    from services.core.config import load_params
    from services.model.params import NodConfig

    cfg = load_params(DEPLOY / "params.example.toml")
    assert cfg == NodConfig()


def test_unknown_param_key_is_named(tmp_path):
    from services.core.config import ConfigError, load_params

    bad = tmp_path / "p.toml"
    bad.write_text("[decision.bias]\nsigmaa = 0.1\n")
    with pytest.raises(ConfigError, match="sigmaa"):
        load_params(bad)
