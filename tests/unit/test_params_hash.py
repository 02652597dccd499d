"""The params hash every heartbeat carries, and the conductor's flags from a rig file."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from services.core import messages as m
from services.core.config import load_params, params_hash
from services.core.limits import max_payload_bytes
from services.experiment.service import build_parser, rig_file_flags
from services.model.params import NodConfig

ROOT = Path(__file__).resolve().parents[2]


def test_the_hash_is_of_the_values_not_of_the_file(tmp_path: Path) -> None:
    default = params_hash(NodConfig())
    assert len(default) == 12 and int(default, 16) >= 0
    assert params_hash(load_params(ROOT / "deploy" / "params.example.toml")) == default
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.write_text("# a comment\n[decision.bias]\nsigma = 0.2\n")
    b.write_text("[decision.bias]\n\nsigma = 0.20\n")
    assert params_hash(load_params(a)) == params_hash(load_params(b)) != default
    faster = dataclasses.replace(NodConfig().protocol, rest_s=NodConfig().protocol.rest_s + 1)
    assert params_hash(dataclasses.replace(NodConfig(), protocol=faster)) != default


def test_the_heartbeat_carries_it_strictly() -> None:
    status = m.NodeStatus(seq=0, t_ns=1, service="decision", params_hash="0123456789ab")
    assert m.decode(m.NodeStatus, m.encode(status)).params_hash == "0123456789ab"
    assert m.decode(m.NodeStatus, m.encode(m.NodeStatus(seq=0, t_ns=1))).params_hash is None
    for bad in ("0123456789AB", "short", "0123456789ab!", "f" * 65):
        forged = m.encode(m.NodeStatus(seq=0, t_ns=1, params_hash=bad))  # msgspec builds it
        with pytest.raises(m.MessageError, match="params_hash"):
            m.decode(m.NodeStatus, forged)
    assert max_payload_bytes(m.NodeStatus) < m.MAX_PAYLOAD_BYTES  # still bounded


RIG = """
[rig]
name = "lab3"
router = "tcp/10.0.0.1:7447"
params = "p.toml"
[hosts.arm]
services = ["decision"]
"""


def test_the_conductor_takes_the_rig_file_as_nod_up_gives_it(tmp_path: Path) -> None:
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG)
    flags = rig_file_flags(rig)
    assert flags == ["--connect", "tcp/10.0.0.1:7447", "--rig", "lab3",
                     "--params", str(tmp_path / "p.toml")]
    args = build_parser().parse_args([*flags, "--rig-file", str(rig)])
    assert (args.connect, args.rig, args.params) == (["tcp/10.0.0.1:7447"], "lab3",
                                                      tmp_path / "p.toml")
    # A flag given on the command line wins; an explicit --connect replaces the rig's router.
    here = ["--connect", "tcp/127.0.0.1:7447", "--params", "other.toml"]
    args = build_parser().parse_args([*rig_file_flags(rig, explicit_connect=True), *here])
    assert args.connect == ["tcp/127.0.0.1:7447"] and args.params == Path("other.toml")
    # A secured lab: the control station's identity, which may drive the protocol.
    rig.write_text(RIG.replace('params = "p.toml"', 'tls = "/etc/nod/tls"'))
    assert rig_file_flags(rig) == ["--config", "/etc/nod/tls/control/zenoh.json5", "--rig", "lab3"]
