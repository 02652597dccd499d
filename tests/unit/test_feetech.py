"""Feetech codec, bus and arm driver, byte-exact, against a servo-bus emulator on a real pty."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest

from services.actuation.arm_path import ArmPoses, locate, locate_on, pose_at, pose_names, pose_on
from services.actuation.calibrate import CalibrationAbortedError, calibrate, config_toml
from services.actuation.feetech import (
    FeetechChecksumError,
    decode_status,
    describe_error,
    ping_packet,
    read_packet,
    sync_write_packet,
    write_packet,
)
from services.actuation.feetech_arm import FeetechArm, FeetechArmConfig
from services.core.config import ConfigError, from_mapping, load_toml
from services.model.behaviour import ArmCommand, OptionsCommand
from services.model.geometry import TableLayout
from services.model.params import NodConfig
from tests.emulators.feetech_emulator import IDS, NAMES, POSES, POSES_BY_N, FeetechBusEmulator
from tests.emulators.links import FAST, LINK
from tests.polling import eventually

ROOT = Path(__file__).resolve().parents[2]
CFG = FeetechArmConfig(
    ids=IDS,
    move_time_s=2.0,
    press_time_s=0.5,
    press_hold_s=0.2,
    poll_interval_s=0.1,
    poses=POSES,
    link=LINK,
)
LAYOUT = TableLayout()


@pytest.fixture
def bus():
    with FeetechBusEmulator({i: 2048 for i in IDS}) as emu:
        yield emu


@pytest.fixture
def arm(bus):
    a = FeetechArm(bus.port, CFG, LAYOUT, home=(0.5, 0.08))
    a.connect()
    a.state(0.0)
    yield a
    a.disconnect()


def goal_map(pose):
    return dict(zip(IDS, pose, strict=True))


def goals_become(bus, pose) -> bool:
    """SYNC_WRITE has no reply: wait until the emulator has applied it."""
    return bus.wait_until(lambda: bus.goals() == goal_map(pose))


# -- codec --------------------------------------------------------------------------------------
def test_packets_match_the_protocol_examples():
    assert ping_packet(1) == bytes.fromhex("ff ff 01 02 01 fb")
    # READ 2 bytes of present position (0x38) from servo 1
    assert read_packet(1, 0x38, 2) == bytes.fromhex("ff ff 01 04 02 38 02 be")
    # WRITE torque enable = 1 on servo 3: chk = ~(3 + 4 + 3 + 0x28 + 1) = ~0x33
    assert write_packet(3, 0x28, b"\x01") == bytes.fromhex("ff ff 03 04 03 28 01 cc")
    pkt = sync_write_packet(0x2A, 2, {1: b"\x00\x08", 2: b"\xff\x0f"})
    body = bytes.fromhex("fe 0a 83 2a 02 01 00 08 02 ff 0f")
    assert pkt == b"\xff\xff" + body + bytes(((~sum(body)) & 0xFF,))
    st = decode_status(bytes.fromhex("ff ff 01 04 00 00 08 f2"))
    assert (st.servo_id, st.error, st.params) == (1, 0, b"\x00\x08")
    with pytest.raises(FeetechChecksumError, match="checksum"):
        decode_status(bytes.fromhex("ff ff 01 04 00 00 08 f3"))
    assert "overload" in describe_error(0x20)


def test_path_interpolation_and_location():
    assert pose_at(POSES, 0.0, 0.0) == POSES.home
    assert pose_at(POSES, 1.0, 0.0) == POSES.above_red
    assert pose_at(POSES, -0.5, 0.0) == (1848, 2098, 1998)
    assert pose_at(POSES, 1.0, 1.0) == POSES.press_red
    assert pose_at(POSES, -1.0, 0.5) == (1648, 2248, 1898)
    assert locate(POSES, (2248, 2098, 1998)) == pytest.approx((0.5, 0.0))
    assert locate(POSES, POSES.press_blue) == pytest.approx((-1.0, 1.0))


def test_config_validation_and_example_file():
    with pytest.raises(ValueError, match="joints"):
        FeetechArmConfig(ids=(1, 2), poses=POSES)
    with pytest.raises(ValueError, match="steps"):
        FeetechArmConfig(ids=IDS, poses=ArmPoses(*[(0, 0, 5000)] * 5))
    with pytest.raises(ValueError, match="calibrate"):
        FeetechArm("/dev/null", FeetechArmConfig(), LAYOUT)
    example = from_mapping(FeetechArmConfig, load_toml(ROOT / "deploy/hardware/arm.example.toml"))
    assert example.poses.calibrated and len(example.ids) == 6
    assert tuple(example.poses.table()) == pose_names(("red", "blue"))  # the paper's five
    with pytest.raises(ConfigError, match="unknown key"):
        from_mapping(FeetechArmConfig, {"move_speed": 1.0})


def test_poses_by_option_name_in_the_arm_file():
    # The paper's five keys are the two-name case: positional, by keyword and from the file alike
    assert POSES.names == ("red", "blue") and POSES.press_blue == (1648, 2348, 1848)
    assert ArmPoses(*POSES.table().values()) == POSES
    assert ArmPoses() == ArmPoses(**dict.fromkeys(pose_names(("red", "blue")), ()))
    three = POSES_BY_N[3]
    assert three.names == NAMES[3] and tuple(three.table()) == pose_names(NAMES[3])
    assert three.select(("green", "red")).names == ("green", "red")
    cfg = FeetechArmConfig(ids=IDS, poses=three, link=LINK)
    assert from_mapping(FeetechArmConfig, tomllib.loads(config_toml(cfg))) == cfg
    with pytest.raises(ConfigError, match=r"poses: unknown pose 'over_red'"):
        from_mapping(FeetechArmConfig, {"poses": {**POSES.table(), "over_red": [1, 2, 3]}})
    with pytest.raises(ConfigError, match="pose above_green has no press_green"):
        from_mapping(FeetechArmConfig, {"poses": {**POSES.table(), "above_green": [1, 2, 3]}})
    with pytest.raises(ConfigError, match="poses: press_red: expected an array of integers"):
        from_mapping(FeetechArmConfig, {"poses": {**POSES.table(), "press_red": [1.5, 2, 3]}})
    with pytest.raises(ValueError, match="two options or more"):
        ArmPoses(home=(1, 2, 3), above_red=(4, 5, 6), press_red=(7, 8, 9))
    with pytest.raises(ValueError) as exc:
        POSES.select(NAMES[3])
    assert str(exc.value) == (
        "the arm file has no press pose for option(s) green (it has red, blue); record them "
        "with `nod actuation calibrate --names red,blue,green`"
    )


def test_the_paper_path_is_the_two_box_star():
    for s in (-1.0, -0.7, -0.25, 0.0, 0.3, 1.0):
        for d in (0.0, 0.5, 1.0) if abs(s) == 1 else (0.0,):
            box = 0 if s >= 0 else 1
            assert pose_at(POSES, s, d) == pose_on(POSES, box, abs(s), d)
    three = POSES_BY_N[3]
    assert locate_on(three, pose_on(three, 2, 0.5, 0.0)) == pytest.approx((2, 0.5, 0.0))
    assert locate_on(three, three.press_green) == pytest.approx((2, 1.0, 1.0))
    assert locate_on(three, three.home)[1:] == (0.0, 0.0)


# -- driver -------------------------------------------------------------------------------------
def test_connect_holds_where_the_arm_is_before_torque_on(bus):
    bus.move_by_hand(2, 2100)  # arm moved while unpowered; a stale goal of 2048 remains
    arm = FeetechArm(bus.port, CFG, LAYOUT)
    arm.connect()
    instrs = [(i, ins, p[:1]) for i, ins, p in bus.packets]
    first_goal = instrs.index((0xFE, 0x83, b"\x2a"))
    first_torque = instrs.index((1, 0x03, b"\x28"))
    assert [i for i, ins, _ in instrs[:3]] == [1, 2, 3] and instrs[0][1] == 0x01  # PINGs
    assert first_goal < first_torque
    assert bus.goals() == {1: 2048, 2: 2100, 3: 2048}
    assert all(s.get("torque_enable") == 1 for s in bus.servos.values())
    assert all(s.get("acceleration") == CFG.acceleration for s in bus.servos.values())
    assert arm.fault is None
    arm.disconnect()


def test_a_move_becomes_goal_positions_on_the_right_ids(bus, arm):
    arm.send(ArmCommand.move(+1))
    bus.take_received()
    st = arm.state(0.5)  # a quarter of the way to red
    expected = pose_at(POSES, 0.25, 0.0)
    assert st.moving and st.target == "red" and st.fault is None
    assert goals_become(bus, expected)
    # the exact SYNC_WRITE: address 0x2A, 6 bytes each: position, time 0, speed, little endian
    data = {
        i: p.to_bytes(2, "little") + b"\x00\x00" + CFG.goal_speed.to_bytes(2, "little")
        for i, p in goal_map(expected).items()
    }
    assert bus.wait_until(lambda: sync_write_packet(0x2A, 6, data) in bus.received)
    st = arm.state(3.0)
    assert goals_become(bus, POSES.above_red) and st.ee == LAYOUT.red.center
    assert not arm.state(3.1).moving


def test_stop_pause_reverse_mid_path(bus, arm):
    arm.send(ArmCommand.move(+1))
    arm.state(1.0)  # s = 0.5
    assert arm.send(ArmCommand.stop("pause")).action == "stop"
    held = goal_map(pose_at(POSES, 0.5, 0.0))
    assert goals_become(bus, pose_at(POSES, 0.5, 0.0))
    st = arm.state(1.1)
    assert not st.moving and bus.goals() == held and st.target is None
    home, red = (0.5, 0.08), LAYOUT.red.center
    assert st.ee == pytest.approx(((home[0] + red[0]) / 2, (home[1] + red[1]) / 2))
    arm.send(ArmCommand.move(-1))
    arm.state(1.6)  # back by 0.25: s = 0.25
    assert arm.path == pytest.approx((0.25, 0.0))
    assert goals_become(bus, pose_at(POSES, 0.25, 0.0))
    arm.state(4.2)  # 1.25 of the path left at 0.5 per second
    assert goals_become(bus, POSES.above_blue)


def test_press_descends_holds_and_returns(bus, arm):
    arm.send(ArmCommand.press("blue"))
    assert arm.send(ArmCommand.move(+1)).target == "blue"  # refused: press committed
    t, pressed_at = 0.0, None
    while t < 4.0:
        t = round(t + 0.05, 2)
        st = arm.state(t)
        if st.pressed and pressed_at is None:
            pressed_at = t
    # 2 s across, 0.5 s down, 0.2 s held
    assert pressed_at == pytest.approx(2.7, abs=0.051)
    assert goal_map(POSES.press_blue) in bus.goal_history
    assert goals_become(bus, POSES.above_blue)  # rose again
    assert st.pressed == "blue" and not st.moving
    arm.home()
    arm.state(8.0)
    assert goals_become(bus, POSES.home) and arm.state(8.1).pressed is None


def test_checksum_errors_are_detected_and_the_arm_holds(bus, arm):
    arm.send(ArmCommand.move(+1))
    arm.state(0.5)
    bus.corrupt_replies = 1
    st = arm.state(0.6)  # health read due
    assert "checksum" in (st.fault or "") and not st.moving
    refused = arm.send(ArmCommand.move(+1))
    assert refused.action == "stop" and "fault" in refused.reason
    st = arm.state(0.75)  # the servos answer again: re-initialised, holding
    assert st.fault is None and arm.path == pytest.approx((0.25, 0.0), abs=0.01)
    assert arm.send(ArmCommand.move(+1)).action == "move"


def test_silence_is_detected_within_a_bounded_time(bus):
    arm = FeetechArm(bus.port, dataclasses.replace(CFG, link=FAST), LAYOUT)
    arm.connect()
    arm.state(0.0)
    bus.silent_ids = {2}
    t0 = time.monotonic()
    st = arm.state(0.2)
    assert time.monotonic() - t0 < 1.0  # 50 ms timeout, not a hang
    assert "no status from servo 2" in (st.fault or "")
    bus.silent_ids = set()
    assert arm.state(0.25).fault is not None  # retried at poll_interval, not every call
    t = 0.25

    def healthy() -> bool:
        nonlocal t
        t += 0.1
        return arm.state(t).fault is None

    assert eventually(healthy)
    arm.disconnect()


def test_servo_error_bits_are_reported(bus, arm):
    bus.error_bits[3] = 0x20
    assert "servo 3 reports overload" in (arm.state(0.2).fault or "")
    bus.error_bits.clear()
    assert arm.state(0.4).fault is None


# -- over N boxes -------------------------------------------------------------------------------
def options_arm(port: str, n: int, poses: ArmPoses | None = None) -> FeetechArm:
    """The arm over a table of n boxes, box j the poses of option NAMES[n][j]."""
    cfg = dataclasses.replace(CFG, poses=POSES_BY_N[n] if poses is None else poses)
    return FeetechArm(port, cfg, NodConfig().table(n), home=(0.5, 0.08), names=NAMES[n])


def run_until(arm: FeetechArm, t: float, until: float, step: float = 0.05):
    """Step the arm from t to `until` (s); its last state."""
    st = arm.state(t)
    while t < until - 1e-9:
        t = round(t + step, 2)
        st = arm.state(t)
    return st


@pytest.mark.parametrize("n", [2, 3])
def test_the_arm_presses_each_box_at_its_options_pose(bus, n):
    arm = options_arm(bus.port, n)
    arm.connect()
    poses, t = POSES_BY_N[n], 0.0
    try:
        for box, name in enumerate(NAMES[n]):
            arm.state(t)
            assert arm.send(OptionsCommand("press", box)).target == box
            refused = arm.send(OptionsCommand("move", (box + 1) % n))
            assert (refused.action, refused.target) == ("press", box)  # press committed
            st = run_until(arm, t, t + 3.5)  # 2 s out, 0.5 s down, 0.2 s held, 0.5 s up
            assert st.pressed == box and st.target == box and not st.moving
            assert goal_map(getattr(poses, f"press_{name}")) in bus.goal_history
            assert goals_become(bus, getattr(poses, f"above_{name}"))  # rose again
            assert st.ee == NodConfig().table(n).boxes[box].center
            arm.home()
            st = run_until(arm, t + 3.5, t + 6.0)
            assert goals_become(bus, poses.home) and st.pressed is None
            t += 6.0
    finally:
        arm.disconnect()


def test_the_paper_arm_is_the_two_option_arm():
    # The same moves by colour and by box index stream the same goals at the same times.
    script = [(0.0, "move", 0), (1.0, "stop", None), (1.2, "move", 1), (3.0, "press", 1),
              (6.5, "home", None), (7.0, "move", 0), (8.0, "press", 0)]
    histories = []
    for by_index in (False, True):
        with FeetechBusEmulator({i: 2048 for i in IDS}) as emu:
            arm = (options_arm(emu.port, 2) if by_index
                   else FeetechArm(emu.port, CFG, LAYOUT, home=(0.5, 0.08)))
            arm.connect()
            steps, t, seen = list(script), 0.0, []
            while t <= 12.0:
                st = arm.state(t)
                while steps and steps[0][0] <= t:
                    _, action, box = steps.pop(0)
                    if action == "home":
                        arm.home()
                    elif by_index:
                        arm.send(OptionsCommand(action, box))
                    elif action == "stop":
                        arm.send(ArmCommand.stop())
                    elif action == "move":
                        arm.send(ArmCommand.move(1 - 2 * box))
                    else:
                        arm.send(ArmCommand.press(("red", "blue")[box]))
                boxes = [b if by_index or b is None else ("red", "blue").index(b)
                         for b in (st.target, st.pressed)]
                seen.append((t, arm.last_goal, st.ee, st.moving, *boxes))
                t = round(t + 0.05, 2)
            arm.disconnect()
            histories.append(seen)
    assert histories[0] == histories[1]
    assert any(row[5] == 1 for row in histories[0]) and histories[0][-1][5] == 0


def test_a_move_to_another_box_goes_back_through_home(bus):
    arm = options_arm(bus.port, 3)
    arm.connect()
    three = POSES_BY_N[3]
    try:
        arm.state(0.0)
        arm.send(OptionsCommand("move", 0))
        arm.state(1.0)  # halfway out to red
        arm.send(OptionsCommand("move", 2))
        arm.state(1.5)  # back a quarter on red's spoke
        assert arm.place == pytest.approx((0, 0.25, 0.0))
        arm.state(2.5)  # home after 0.5 s, then a quarter out on green's
        assert arm.place == pytest.approx((2, 0.25, 0.0))
        assert goals_become(bus, pose_on(three, 2, 0.25, 0.0))
        assert goal_map(three.home) in bus.goal_history  # through home, never across
        st = run_until(arm, 2.5, 4.5)
        assert goals_become(bus, three.above_green) and st.target == 2 and not st.moving
        with pytest.raises(ValueError, match="box 3 is not on this table of 3 boxes"):
            arm.send(OptionsCommand("move", 3))
    finally:
        arm.disconnect()


@pytest.mark.parametrize("n", [2, 3])
def test_a_bus_fault_freezes_the_arm_over_any_number_of_boxes(bus, n):
    arm = options_arm(bus.port, n)
    arm.connect()
    try:
        arm.state(0.0)
        arm.send(OptionsCommand("move", n - 1))
        arm.state(0.5)
        bus.corrupt_replies = 1
        st = arm.state(0.6)  # health read due
        assert "checksum" in (st.fault or "") and not st.moving
        refused = arm.send(OptionsCommand("press", n - 1))
        assert refused.action == "stop" and "fault" in refused.reason
        st = arm.state(0.75)  # the servos answer again: re-initialised, holding
        assert st.fault is None and arm.place == pytest.approx((n - 1, 0.25, 0.0), abs=0.01)
    finally:
        arm.disconnect()


def test_an_arm_file_without_a_pose_for_every_option_is_refused(tmp_path):
    with pytest.raises(ValueError, match=r"option\(s\) green \(it has red, blue\)"):
        options_arm("/dev/null", 3, poses=POSES)
    arm_file = tmp_path / "arm.toml"
    arm_file.write_text(config_toml(FeetechArmConfig(ids=IDS, poses=POSES, link=LINK)))
    res = subprocess.run(
        [sys.executable, "-m", "services.cli", "actuation", "--options", "3", "--driver",
         "feetech", "--port", "/dev/null", "--arm-config", str(arm_file),
         "--state-dir", str(tmp_path / "state")],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )
    assert res.returncode != 0
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert f"{arm_file}: the arm file has no press pose for option(s) green" in lines[0]
    assert "--names red,blue,green" in lines[0]


# -- calibration --------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [2, 3])
def test_calibrate_records_poses_by_hand(bus, tmp_path, n):
    poses = POSES_BY_N[n]
    targets = list(poses.table().values())  # home, then above and press of each option
    asked: list[str] = []

    def prompt(message: str) -> str:
        asked.append(message)
        if len(asked) > 1:  # the first prompt only warns that torque goes off
            for i, p in zip(IDS, targets[len(asked) - 2], strict=True):
                bus.move_by_hand(i, p)
        return ""

    out = tmp_path / "arm.toml"
    base = FeetechArmConfig(ids=IDS, link=LINK)
    names = None if n == 2 else NAMES[n]  # the paper's red and blue by default
    result = calibrate(bus.port, out, base, prompt=prompt, say=lambda _: None, names=names)
    assert result.poses == poses
    assert "OFF" in asked[0] and f"PRESS_{NAMES[n][-1].upper()}" in asked[-1]
    assert len(asked) == 1 + len(targets)
    assert all(s.get("torque_enable") == 0 for s in bus.servos.values())
    assert from_mapping(FeetechArmConfig, load_toml(out)) == result


def test_calibrate_abort_writes_nothing(bus, tmp_path):
    out = tmp_path / "arm.toml"
    with pytest.raises(CalibrationAbortedError):
        calibrate(bus.port, out, FeetechArmConfig(ids=IDS, link=LINK), prompt=lambda _: "q")
    assert not out.exists()


def test_factory_builds_each_arm_driver():
    from services.actuation.drivers import make_arm_driver
    from services.actuation.threaded_arm import ThreadedArm
    from services.model.arm import SimArm
    from services.model.arm_kinematics import SimArmParams

    example = ROOT / "deploy/hardware/arm.example.toml"
    sim = make_arm_driver("sim", None, None, LAYOUT, SimArmParams(), t0=5.0)
    assert isinstance(sim, SimArm) and sim.t == 5.0
    arm = make_arm_driver("feetech", "/dev/ttyACM0", example, LAYOUT, SimArmParams(home=(0.4, 0.1)))
    assert isinstance(arm, ThreadedArm) and isinstance(arm.inner, FeetechArm)
    assert arm.inner.home_point == (0.4, 0.1)
    assert not arm.is_connected
    with pytest.raises(ValueError, match="calibrate"):
        make_arm_driver("feetech", "/dev/ttyACM0", None, LAYOUT, None)
    with pytest.raises(ValueError, match="--port"):
        make_arm_driver("feetech", None, example, LAYOUT, None)
