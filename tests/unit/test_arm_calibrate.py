"""`nod actuation calibrate` refuses duplicate and unreachable poses (Feetech emulator, pty)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from services.actuation.arm_path import pose_names
from services.actuation.calibrate import (
    DUPLICATE_STEPS,
    REACH_STEPS,
    VERIFY_ROUTE,
    PoseRejectedError,
    calibrate,
    check_pose,
    config_toml,
    read_limits,
    verify_route,
)
from services.actuation.feetech import FeetechBus
from services.actuation.feetech_arm import FeetechArmConfig
from services.core.config import from_mapping, load_toml
from services.core.serial_link import SerialLink
from tests.emulators.feetech_emulator import IDS, NAMES, POSES, POSES_BY_N, FeetechBusEmulator
from tests.emulators.links import LINK

ROOT = Path(__file__).resolve().parents[2]
ORDER = pose_names(NAMES[3])  # every pose any test here records, the paper's five first
BASE = FeetechArmConfig(ids=IDS, link=LINK)


@pytest.fixture
def bus(tmp_path):
    with FeetechBusEmulator({i: 2048 for i in IDS}, link_dir=tmp_path) as emu:
        yield emu


def by_hand(bus: FeetechBusEmulator, poses: dict[str, tuple[int, ...]], asked: list[str]):
    """A prompt that moves the arm to the asked pose, as the operator would."""

    def prompt(message: str) -> str:
        asked.append(message)
        for name in ORDER:
            if f"to {name.upper()}:" in message:
                for i, p in zip(IDS, poses[name], strict=True):
                    bus.move_by_hand(i, p)
        return ""

    return prompt


def test_the_duplicate_tolerance_is_inclusive_and_per_series():
    tol = DUPLICATE_STEPS["sts"]
    limits = {i: (0, 4095) for i in IDS}
    near = (2048 + tol, 2048 - tol, 2048)
    with pytest.raises(PoseRejectedError, match=f"same as home: every joint within {tol} steps"):
        check_pose("above_red", near, {"home": POSES.home}, IDS, limits, tol)
    check_pose("above_red", (2048 + tol + 1, 2048, 2048), {"home": POSES.home}, IDS, limits, tol)
    # the same angle on both families: ~0.9°
    for series, steps in DUPLICATE_STEPS.items():
        turn = {"sts": 4096, "scs": 1024}[series]
        assert 0.7 <= steps * 360 / turn <= 1.1
    assert REACH_STEPS["sts"] > DUPLICATE_STEPS["sts"]
    assert set(VERIFY_ROUTE) == set(pose_names(NAMES[2]))
    assert verify_route(NAMES[2]) == VERIFY_ROUTE
    assert verify_route(NAMES[3])[-4:] == ("above_green", "press_green", "above_green", "home")


def test_limits_are_read_from_the_servos(bus):
    bus.set_limits(2, 1000, 3000)
    bus.set_limits(3, 0, 0)  # unset (multi-turn / wheel): the whole turn
    link = SerialLink(bus.port, BASE.baudrate, LINK)
    link.open()
    try:
        assert read_limits(FeetechBus(link), IDS, "sts") == {
            1: (0, 4095),
            2: (1000, 3000),
            3: (0, 4095),
        }
    finally:
        link.close()


def test_a_duplicate_pose_is_refused_and_nothing_written(bus, tmp_path):
    out = tmp_path / "arm.toml"
    poses = POSES.table()
    poses["press_red"] = (2451, 2146, 1948)  # Enter pressed again above red: 3 steps of noise
    asked: list[str] = []
    with pytest.raises(PoseRejectedError) as exc:
        calibrate(bus.port, out, BASE, prompt=by_hand(bus, poses, asked), say=lambda _: None)
    msg = str(exc.value)
    assert "pose press_red is the same as above_red" in msg and "nothing written" in msg
    assert "\n" not in msg
    assert not out.exists()
    assert not any("ABOVE_BLUE" in a for a in asked)  # refused at once, not after every pose
    assert all(s.get("torque_enable") == 0 for s in bus.servos.values())


def test_a_pose_outside_a_servos_limits_is_refused_and_nothing_written(bus, tmp_path):
    out = tmp_path / "arm.toml"
    bus.set_limits(2, 1024, 2300)  # the elbow may not go past 2300: press_red (2348) is beyond
    poses = POSES.table()
    with pytest.raises(PoseRejectedError) as exc:
        calibrate(bus.port, out, BASE, prompt=by_hand(bus, poses, []), say=lambda _: None)
    assert str(exc.value).startswith(
        "pose press_red is unreachable: servo 2 is at 2348, outside its angle limits [1024, 2300]"
    )
    assert not out.exists()


@pytest.mark.parametrize("n", [2, 3])
def test_verify_drives_every_pose_then_writes(bus, tmp_path, n):
    out = tmp_path / "arm.toml"
    expected = POSES_BY_N[n]
    poses = expected.table()
    asked: list[str] = []
    result = calibrate(
        bus.port, out, BASE, prompt=by_hand(bus, poses, asked), say=lambda _: None, verify=True,
        names=NAMES[n],
    )
    assert result.poses == expected
    assert "Torque goes ON" in asked[-1]
    visited = [tuple(g[i] for i in IDS) for g in bus.goal_history]
    route = [poses[name] for name in verify_route(NAMES[n])]
    assert visited[-len(route) :] == route  # the whole route, in order, one goal per pose
    last = poses[f"press_{NAMES[n][-1]}"]
    assert visited[0] == last  # first: hold where the operator left it, torque on
    assert bus.positions() == dict(zip(IDS, expected.home, strict=True))
    assert all(s.get("torque_enable") == 1 for s in bus.servos.values())
    assert from_mapping(FeetechArmConfig, load_toml(out)) == result


def test_verify_refuses_a_pose_a_servo_does_not_reach(bus, tmp_path):
    out = tmp_path / "arm.toml"
    poses = POSES.table()

    def prompt(message: str) -> str:
        if "Torque goes ON" in message:
            bus.block(3)  # the wrist jams after the poses were recorded (at press_blue)
        return by_hand(bus, poses, [])(message)

    with pytest.raises(PoseRejectedError) as exc:
        calibrate(
            bus.port, out, BASE, prompt=prompt, say=lambda _: None, verify=True,
            verify_timeout_s=0.3,
        )
    assert str(exc.value).startswith(
        "pose above_blue is unreachable: servo 3 stopped at 1848, commanded 1948 (off by 100 > 40"
    )
    assert not out.exists()
    held = {1: 1648, 2: 2148, 3: 1848}  # where it stopped: no straining against the jam
    assert bus.wait_until(lambda: bus.goals() == held)  # SYNC_WRITE has no reply: wait for it


def _calibrate(port: str, *args: str, stdin: str = "") -> subprocess.CompletedProcess[str]:
    """`nod actuation calibrate --port PORT ARGS…` as an operator runs it, typing `stdin`."""
    return subprocess.run(
        [sys.executable, "-m", "services.cli", "actuation", "calibrate", "--port", port, *args],
        cwd=ROOT, input=stdin, capture_output=True, text=True, timeout=30,
    )


def test_the_cli_refuses_an_arm_that_was_never_moved(bus, tmp_path):
    base = tmp_path / "base.toml"
    base.write_text(config_toml(BASE))
    out = tmp_path / "arm.toml"
    res = _calibrate(bus.port, "--out", str(out), "--base", str(base), stdin="\n" * 6)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert "pose above_red is the same as home" in lines[0]
    assert not out.exists()


def test_the_cli_records_the_poses_of_the_named_options(bus, tmp_path):
    # --names red,blue,green: seven poses, prompted in order; a --base of three names keeps them
    base = tmp_path / "base.toml"
    base.write_text(config_toml(BASE))
    out = tmp_path / "arm.toml"
    res = _calibrate(bus.port, "--out", str(out), "--base", str(base), "--names",
                     "red,blue,green", stdin="q\n")
    assert res.returncode == 2 and "aborted" in res.stderr and not out.exists()
    res = _calibrate(bus.port, "--out", str(out), "--names", "red,red")
    assert res.returncode == 2 and "--names needs two or more distinct" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1


def test_the_cli_rejects_a_bad_verify_timeout(tmp_path):
    res = subprocess.run(
        [sys.executable, "-m", "services.cli", "actuation", "calibrate", "--port", "/dev/null"]
        + ["--out", str(tmp_path / "a.toml"), "--verify", "--verify-timeout", "nan"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert res.returncode == 2 and "--verify-timeout" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
