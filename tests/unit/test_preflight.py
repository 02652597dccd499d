"""The preflight refuses unsafe or absurd values before anything starts, in one line naming the key.

`nod up --dry-run` (and deploy/setup-host, which runs it) reads the rig file and the params file;
a value a service would refuse only once started (and then be restarted until given up), or a
protocol time that would stall a session for hours, is an exit 2 with one line here.
"""

from __future__ import annotations

import math
import typing
from pathlib import Path

import pytest

from services.core import messages as m
from services.core.config import ConfigError, load_params
from services.launch import up
from services.model import gaze, protocol

RIG = """
[rig]
name = "rig1"
router = "tcp/127.0.0.1:7447"
params = "p.toml"
[hosts.arm]
services = ["decision", "actuation", "eyes"]
[actuation]
driver = "sim"
stale_ms = 250
"""


def preflight(tmp_path: Path, capsys, params: str = "", rig: str = RIG) -> tuple[int, str]:
    (tmp_path / "p.toml").write_text(params)
    (tmp_path / "rig.toml").write_text(rig)
    code = up.main([str(tmp_path / "rig.toml"), "--dry-run"])
    return code, capsys.readouterr().err


@pytest.mark.parametrize(
    ("params", "rig_change", "key"),
    [
        ("[protocol]\nrest_s = 1e12\n", None, "rest_s"),
        ("", ("stale_ms = 250", "stale_ms = -4"), "actuation.stale_ms"),
        ("", ("stale_ms = 250", "stale_ms = 250\n[eyes]\nstale_ms = 0"), "eyes.stale_ms"),
        ("[protocol]\ntrial_timeout_s = 10000\n", None, "trial_timeout_s"),  # ms for s
        ("[protocol]\nmax_attempts = 1000000\n", None, "max_attempts"),
        ("[protocol.gesture]\nflicks = 1000000000\n", None, "flicks"),
    ],
)
def test_nod_up_dry_run_refuses_in_one_line_naming_the_key(
    tmp_path: Path, capsys, params: str, rig_change: tuple[str, str] | None, key: str
) -> None:
    rig = RIG.replace(*rig_change) if rig_change else RIG
    code, err = preflight(tmp_path, capsys, params, rig)
    assert code == 2
    assert err.count("\n") == 1 and key in err, err
    print(f"\n{err.strip()}")


def test_a_sane_rig_passes_the_preflight(tmp_path: Path, capsys) -> None:
    code, err = preflight(tmp_path, capsys)
    assert code == 0 and err == ""


@pytest.mark.parametrize(
    ("key", "bad", "good"),
    [
        ("countdown_interval_s", 750, 10),
        ("trial_timeout_s", 121, 120),
        ("gaze_lead_s", 1000, 60),
        ("robot_wait_s", 5000, 60),
        ("rest_s", 1e12, 600),
        ("rest_s", float("inf"), 0),
        ("max_attempts", 11, 10),
        ("target_clicks", 1001, 1000),
    ],
)
def test_protocol_keys_are_bounded(tmp_path: Path, key: str, bad: float, good: float) -> None:
    path = tmp_path / "p.toml"
    path.write_text(f"[protocol]\n{key} = {good}\n")
    assert getattr(load_params(path).protocol, key) == good
    path.write_text(f"[protocol]\n{key} = {bad}\n")
    with pytest.raises(ConfigError, match=f"protocol: ProtocolParams.{key} must be") as info:
        load_params(path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("[protocol.gesture]\nlimit_yaw = 7.0\n", "limit_yaw"),
        ("[protocol.gesture]\nlimit_pitch = -4.0\n", "limit_pitch"),
        ("[protocol.gesture]\nhold_s = 3600\n", "hold_s"),
        ("[protocol.gesture]\nflicks = 21\n", "flicks"),
        (
            '[[protocol.trials]]\nindex = 1\nmode = "dissensus"\nyaw = 4.0\n',
            "trial 1: gaze yaw",
        ),
    ],
)
def test_gaze_angles_and_the_gesture_are_bounded(tmp_path: Path, text: str, key: str) -> None:
    path = tmp_path / "p.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=key) as info:
        load_params(path)
    assert "\n" not in str(info.value)


def _wire_bound(alias: typing.Any) -> float:
    meta = typing.get_args(alias)[1]
    return meta.le


def test_the_model_bounds_are_the_wire_bounds() -> None:
    # A schedule or gaze the messages cannot carry would be refused by every subscriber.
    assert _wire_bound(m.Trial) == protocol.MAX_TRIALS
    assert _wire_bound(m.Radians) == protocol.MAX_GAZE_RAD
    assert gaze.AttentionGestureParams(limit_yaw=protocol.MAX_GAZE_RAD).limit_yaw == math.pi
