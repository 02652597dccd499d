"""The deploy folder's Zenoh configs load, and every systemd unit points at a real role."""

from pathlib import Path

import pytest
import zenoh

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


@pytest.mark.parametrize("name", ["router.json5", "client.json5", "single-host.json5"])
def test_zenoh_configs_parse(name):
    conf = zenoh.Config.from_file(str(DEPLOY / "zenoh" / name))
    assert conf.get_json("mode") in ('"router"', '"client"', "router", "client")
    assert conf.get_json("scouting/multicast/enabled") in ("false", False)


def test_systemd_units_use_known_roles():
    launch = (DEPLOY / "lab" / "launch").read_text()
    units = sorted((DEPLOY / "systemd").glob("nod-*.service"))
    assert len(units) == 4
    for unit in units:
        role = unit.stem.removeprefix("nod-")
        assert f"  {role})" in launch
        assert f"launch {role}" in unit.read_text()
