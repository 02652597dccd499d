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
    assert int(conf.get_json("transport/link/rx/max_message_size")) == 1 << 20


def test_systemd_units_use_known_roles():
    launch = (DEPLOY / "lab" / "launch").read_text()
    units = sorted((DEPLOY / "systemd").glob("nod-*.service"))
    assert len(units) == 4
    for unit in units:
        role = unit.stem.removeprefix("nod-")
        assert f"  {role})" in launch
        assert f"launch {role}" in unit.read_text()


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
