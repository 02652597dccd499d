"""`nod eyes point` and `nod eyes calibrate` against the Maestro and Arduino emulators on real ptys.

Expected bytes are computed here from the mapping in docs/hardware.md (angle = 90 + direction ·
degrees(gaze) + trim, clamped; pulse linear over 0–180°) and the two protocols (Maestro Set
Target in ¼ µs; the sketch's SET_PULSES frame of PROTOCOL.md), not from the code under test.
"""

from __future__ import annotations

import math
import os
import re
import signal
import struct
import subprocess
import sys
import threading
import time
from functools import partial
from pathlib import Path

import pytest

from services.cli import main
from services.core.config import ConfigError
from services.eyes.calibrate import TrimSession, parse_set, stream_keys
from services.eyes.drivers import make_eyes_driver
from services.eyes.maestro import MaestroConfig, MaestroServoDriver
from services.eyes.trims import EyesTrims, apply_trims, load_trims
from services.model.gaze import GazeCommand
from services.model.servos import EyesCalibration, ServoCalibration, servo_targets
from tests.emulators.arduino_emulator import ArduinoEyesEmulator, crc8_smbus
from tests.emulators.links import LINK
from tests.emulators.maestro_emulator import SET_TARGET, MaestroEmulator
from tests.polling import eventually
from tests.processes import run_nod

ROOT = Path(__file__).resolve().parents[2]
NAMES = ("left_pan", "left_tilt", "right_pan", "right_tilt")
CHANNELS = (3, 2, 1, 0)  # rewired on purpose: the bytes must follow [maestro] channels
# name: (trim_deg, direction, min_deg, max_deg, min_pulse_us, max_pulse_us)
CAL = {
    "left_pan": (2.0, 1, 10.0, 170.0, 500.0, 2500.0),
    "left_tilt": (0.0, 1, 30.0, 150.0, 500.0, 2500.0),
    "right_pan": (-1.0, 1, 10.0, 170.0, 500.0, 2500.0),
    "right_tilt": (0.0, -1, 30.0, 150.0, 600.0, 2400.0),
}
EYES_TOML = "\n".join(
    [
        *(
            f"[calibration.{n}]\ntrim_deg = {t}\ndirection = {d}\nmin_deg = {lo}\n"
            f"max_deg = {hi}\nmin_pulse_us = {p0}\nmax_pulse_us = {p1}\n"
            for n, (t, d, lo, hi, p0, p1) in CAL.items()
        ),
        f"[maestro]\nchannels = {list(CHANNELS)}\n[maestro.link]\ntimeout_s = 0.5\n",
        "[arduino]\nboot_wait_s = 2.0\n[arduino.link]\ntimeout_s = 0.5\n",
    ]
)


def expected_pulses(yaw: float, pitch: float, trims: dict[str, float] | None = None) -> list:
    out = []
    for name, g in zip(NAMES, (yaw, pitch, yaw, pitch), strict=True):
        trim, d, lo, hi, p0, p1 = CAL[name]
        trim = (trims or {}).get(name, trim)
        angle = min(max(90.0 + d * math.degrees(g) + trim, lo), hi)
        out.append(p0 + angle / 180.0 * (p1 - p0))
    return out


def maestro_bytes(pulses) -> bytes:
    """Set Target, channel, low 7 bits, high 7 bits of the ¼ µs target — per servo."""
    out = b""
    for ch, p in zip(CHANNELS, pulses, strict=True):
        q = round(p * 4)
        out += bytes((SET_TARGET, ch, q & 0x7F, q >> 7))
    return out


def arduino_frame(pulses) -> bytes:
    body = bytes((0x02, 8)) + struct.pack("<4H", *(round(p) for p in pulses))
    return b"\xa5" + body + bytes((crc8_smbus(body),))


def set_targets(raw: bytes) -> list[tuple[float, ...]]:
    """Every group of four Set Targets in the byte stream, as µs in SERVO_NAMES order."""
    groups, current, i = [], {}, 0
    while i + 3 < len(raw):
        if raw[i] == SET_TARGET and raw[i + 1] in CHANNELS:
            current[raw[i + 1]] = (raw[i + 2] | raw[i + 3] << 7) / 4.0
            if len(current) == 4:
                groups.append(tuple(current[ch] for ch in CHANNELS))
                current = {}
            i += 4
        else:
            i += 1
    return groups


@pytest.fixture
def eyes_toml(tmp_path) -> Path:
    path = tmp_path / "eyes.toml"
    path.write_text(EYES_TOML)
    return path


@pytest.fixture
def maestro(tmp_path):
    with MaestroEmulator(link_dir=tmp_path) as emu:
        yield emu


@pytest.fixture
def board(tmp_path):
    with ArduinoEyesEmulator(link_dir=tmp_path) as emu:
        yield emu


nod = partial(run_nod, timeout=30)


def one_line_error(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# -- the model's pieces used by the tools ---------------------------------------------------------
def test_expected_values_agree_with_the_model(eyes_toml):
    calib = make_eyes_driver("sim", None, eyes_toml).calibration
    for yaw, pitch in [(0.0, 0.0), (0.53, -0.31), (2.0, -1.5), (-0.47, 0.31)]:
        got = servo_targets(GazeCommand(yaw, pitch), calib).pulses_us
        assert got == pytest.approx(expected_pulses(yaw, pitch))


def test_trims_file_is_validated_on_load(tmp_path):
    bad = {
        "[trim_deg]\nleft_pan = 25.0\n": "within ±20",
        "[trim_deg]\nleft_pann = 1.0\n": "unknown key",
        '[trim_deg]\nleft_pan = "x"\n': "expected a number",
        "[trims]\nleft_pan = 1.0\n": "no [trim_deg]",
        "[trim_deg\n": "not valid TOML",
    }
    for text, why in bad.items():
        path = tmp_path / "t.toml"
        path.write_text(text)
        with pytest.raises(ConfigError, match=re.escape(why)) as exc:
            load_trims(path)
        assert "\n" not in str(exc.value) and str(path) in str(exc.value)
    # within ±20° but past a servo's limits: refused when laid over that calibration
    narrow = EyesCalibration(left_pan=ServoCalibration(min_deg=80.0, max_deg=93.0))
    with pytest.raises(ConfigError, match="outside the servo's limits"):
        apply_trims(narrow, EyesTrims(left_pan=5.0))


def test_trim_session_keys_and_set_spec():
    s = TrimSession(EyesCalibration(), step_deg=0.5)
    actions = [s.key(k) for k in stream_keys("dd\x1b[C2wS")]
    assert actions == ["changed", "changed", "changed", None, "changed", "changed"]
    assert s.trims == {"left_pan": 1.5, "left_tilt": 0.0, "right_pan": 0.0, "right_tilt": -2.0}
    s.key("0")
    assert s.trims["right_tilt"] == 0.0 and s.trims["left_pan"] == 1.5
    s.key("1")
    for _ in range(20):
        s.key("D")  # 5 steps each: runs into ±20°
    assert s.trims["left_pan"] == 19.0 and "refused" in s.message
    assert s.key("x") is None and "unknown key" in s.message
    assert s.key("\n") == "accept" and s.key("q") == "abort"
    assert parse_set("left_pan=+1.5, right_tilt=-0.01rad") == {
        "left_pan": 1.5,
        "right_tilt": pytest.approx(-0.5729578),
    }
    bad = {"left_pn=1": "NAME=DEG", "left_pan=abc": "not a number", "": "at least"}
    for spec, why in bad.items():
        with pytest.raises(ValueError, match=why):
            parse_set(spec)


# -- nod eyes point -------------------------------------------------------------------------------
def test_point_sends_the_expected_bytes_to_a_maestro(maestro, eyes_toml, capsys):
    yaw, pitch = 0.53, -0.31
    rc = main(
        ["eyes", "point", "--yaw", str(yaw), "--pitch", str(pitch), "--driver", "maestro"]
        + ["--port", maestro.port, "--eyes-config", str(eyes_toml)]
    )
    out, err = capsys.readouterr()
    assert rc == 0, err
    want = expected_pulses(yaw, pitch)
    assert maestro_bytes(want) + bytes((0xA1,)) in bytes(maestro.received)  # then Get Errors
    assert maestro.targets_us(CHANNELS) == tuple(round(p * 4) / 4 for p in want)
    assert "clamped" not in out + err
    assert f"{want[0]:.1f}" in out and f"{want[3]:.1f}" in out  # the table shows what was sent


def test_point_sends_the_expected_frame_to_the_arduino(board, eyes_toml, capsys):
    yaw, pitch = -0.47, 0.31  # the "minimal" level toward blue
    rc = main(
        ["eyes", "point", "--yaw", str(yaw), "--pitch", str(pitch), "--driver", "arduino"]
        + ["--port", board.port, "--eyes-config", str(eyes_toml)]
    )
    assert rc == 0, capsys.readouterr().err
    want = expected_pulses(yaw, pitch)
    assert arduino_frame(want) in bytes(board.received)
    assert board.pulses == [round(p) for p in want]


def test_point_reports_clamping_and_never_sends_past_a_limit(maestro, eyes_toml, capsys):
    rc = main(
        ["eyes", "point", "--yaw", "2.0", "--pitch", "-1.5", "--driver", "maestro"]
        + ["--port", maestro.port, "--eyes-config", str(eyes_toml)]
    )
    out, err = capsys.readouterr()
    assert rc == 0, err
    for name in NAMES:
        assert f"clamped {name}" in err
    assert "the gaze asks 206.59°, sent 170° (max_deg)" in err  # left pan: 90 + 114.59 + 2
    assert "sent 30° (min_deg)" in err  # left tilt: 90 − 85.94
    sent = set_targets(bytes(maestro.received))
    assert sent == [tuple(round(p * 4) / 4 for p in expected_pulses(2.0, -1.5))]
    limits = [(p0 + lo / 180 * (p1 - p0), p0 + hi / 180 * (p1 - p0)) for _, _, lo, hi, p0, p1 in
              CAL.values()]
    assert all(lo - 0.25 <= p <= hi + 0.25 for p, (lo, hi) in zip(sent[0], limits, strict=True))


def test_point_hold_returns_to_neutral(board, eyes_toml, capsys):
    t0 = time.monotonic()
    rc = main(
        ["eyes", "point", "--yaw", "0.3", "--driver", "arduino", "--port", board.port]
        + ["--eyes-config", str(eyes_toml), "--hold", "0.3"]
    )
    assert rc == 0, capsys.readouterr().err
    assert time.monotonic() - t0 >= 0.3
    sets = [payload for cmd, payload in board.frames if cmd == 0x02]
    pose, neutral = expected_pulses(0.3, 0.0), expected_pulses(0.0, 0.0)
    assert [struct.unpack("<4H", p) for p in sets] == [
        tuple(round(p) for p in pose),
        tuple(round(p) for p in neutral),
    ]
    assert "back to neutral" in capsys.readouterr().out


def test_point_ctrl_c_returns_to_neutral(maestro, eyes_toml):
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "eyes", "point", "--yaw", "-0.4"]
        + ["--driver", "maestro", "--port", maestro.port, "--eyes-config", str(eyes_toml)]
        + ["--hold", "30"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        pose = tuple(round(p * 4) / 4 for p in expected_pulses(-0.4, 0.0))
        assert eventually(lambda: maestro.targets_us(CHANNELS) == pose, 10.0)
        time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)  # a loaded machine: the bound is "it exits"
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "interrupted; eyes back to neutral" in err and "Traceback" not in err
    neutral = tuple(round(p * 4) / 4 for p in expected_pulses(0.0, 0.0))
    assert set_targets(bytes(maestro.received)) == [pose, neutral]


def test_point_refuses_a_port_the_eyes_service_holds(maestro, eyes_toml):
    service_side = MaestroServoDriver(maestro.port, MaestroConfig(link=LINK))
    service_side.connect()  # what `nod eyes --driver maestro` holds while it runs
    try:
        before = bytes(maestro.received)
        res = nod("eyes", "point", "--yaw", "0.2", "--driver", "maestro", "--port", maestro.port)
        assert res.returncode == 2
        line = one_line_error(res.stderr)
        assert "held by another program" in line and "nod eyes" in line
        assert set_targets(bytes(maestro.received)[len(before) :]) == []
    finally:
        service_side.disconnect()


@pytest.mark.parametrize(
    ("args", "why"),
    [
        (["--yaw", "abc"], "--yaw"),
        (["--yaw", "inf"], "finite"),
        (["--yaw", "0.1", "--hold", "-1"], ">= 0"),
        (["--yaw", "0.1", "--driver", "maestro"], "--port"),
        (["--yaw", "0.1", "--driver", "maestro", "--port", "/dev/nod-no-such-port"], "cannot open"),
    ],
)
def test_point_bad_input_is_one_line_and_exit_2(args, why):
    res = nod("eyes", "point", *args)
    assert res.returncode == 2
    assert why in one_line_error(res.stderr)


def test_point_bad_trims_file_is_one_line_and_exit_2(tmp_path):
    bad = tmp_path / "trims.toml"
    bad.write_text("[trim_deg]\nleft_pan = 40.0\n")
    res = nod("eyes", "point", "--yaw", "0.1", "--trims", str(bad))
    assert res.returncode == 2
    assert "±20" in one_line_error(res.stderr)


# -- nod eyes calibrate ---------------------------------------------------------------------------
def test_calibrate_set_writes_trims_that_the_driver_applies(maestro, eyes_toml, tmp_path, capsys):
    out = tmp_path / "eyes_trims.toml"
    rc = main(
        ["eyes", "calibrate", "--driver", "maestro", "--port", maestro.port]
        + ["--eyes-config", str(eyes_toml), "--out", str(out)]
        + ["--set", "left_pan=+1.5,right_tilt=-0.75"]
    )
    assert rc == 0, capsys.readouterr().err
    # untouched servos keep the eyes file's trims; the set ones are replaced
    trims = {"left_pan": 1.5, "left_tilt": 0.0, "right_pan": -1.0, "right_tilt": -0.75}
    assert load_trims(out).as_dict() == trims
    assert "[trim_deg]" in out.read_text()
    neutral = tuple(round(p * 4) / 4 for p in expected_pulses(0.0, 0.0, trims))
    assert maestro.targets_us(CHANNELS) == neutral  # the eyes show the trimmed centre

    # the same file through the eyes service's driver factory: every target shifts by the trim
    plain = make_eyes_driver("sim", None, eyes_toml)
    trimmed = make_eyes_driver("sim", None, eyes_toml, trims=out)
    with plain, trimmed:
        a, b = plain.look(GazeCommand(0.2, -0.1)), trimmed.look(GazeCommand(0.2, -0.1))
    shift = [trims[n] - CAL[n][0] for n in NAMES]
    assert [y - x for x, y in zip(a.angles_deg, b.angles_deg, strict=True)] == pytest.approx(shift)


def test_calibrate_reads_keys_from_stdin(board, eyes_toml, tmp_path):
    out = tmp_path / "eyes_trims.toml"
    base = ["eyes", "calibrate", "--driver", "arduino", "--port", board.port]
    base += ["--eyes-config", str(eyes_toml), "--out", str(out), "--step", "0.25"]
    res = nod(*base, input="ddd2ss\n")
    assert res.returncode == 0, res.stderr
    trims = {"left_pan": 2.75, "left_tilt": 0.0, "right_pan": -1.0, "right_tilt": -0.5}
    assert load_trims(out).as_dict() == trims
    assert board.pulses == [round(p) for p in expected_pulses(0.0, 0.0, trims)]

    out.unlink()
    for keys, why in {"ddq": "quit", "dd": "ended before Enter"}.items():
        res = nod(*base, input=keys)
        assert res.returncode == 2 and why in one_line_error(res.stderr)
        assert not out.exists()
    # quitting puts the eyes back on the trims they started with
    assert board.pulses == [round(p) for p in expected_pulses(0.0, 0.0)]


def test_calibrate_on_a_terminal(maestro, eyes_toml, tmp_path):
    out = tmp_path / "eyes_trims.toml"
    master, slave = os.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "eyes", "calibrate", "--driver", "maestro"]
        + ["--port", maestro.port, "--eyes-config", str(eyes_toml), "--out", str(out)],
        cwd=ROOT,
        stdin=slave,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    os.close(slave)
    shown = bytearray()
    reader = threading.Thread(target=read_into, args=(proc.stdout, shown), daemon=True)
    reader.start()
    try:
        neutral = tuple(round(p * 4) / 4 for p in expected_pulses(0.0, 0.0))
        assert eventually(lambda: maestro.targets_us(CHANNELS) == neutral, 10.0)
        assert eventually(lambda: b"step 0.5" in shown, 10.0)  # the status line: keys are read
        os.write(master, b"\x1b[C")  # → : left pan +0.5°
        nudged = tuple(round(p * 4) / 4 for p in expected_pulses(0.0, 0.0, {"left_pan": 2.5}))
        assert eventually(lambda: maestro.targets_us(CHANNELS) == nudged, 5.0)
        assert b"+2.50" in shown or eventually(lambda: b"+2.50" in shown, 5.0)
        os.write(master, b"\r")
        proc.wait(timeout=10)
        reader.join(5.0)
    finally:
        os.close(master)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, proc.stderr.read() if proc.stderr else ""
    assert load_trims(out).left_pan == 2.5
    assert b"wrote" in shown


def read_into(stream, buffer: bytearray) -> None:
    while chunk := stream.read1(4096):
        buffer.extend(chunk)


def test_calibrate_refuses_a_trim_past_the_limits(tmp_path):
    out = tmp_path / "t.toml"
    res = nod("eyes", "calibrate", "--out", str(out), "--set", "left_pan=+25")
    assert res.returncode == 2 and "±20" in one_line_error(res.stderr)
    res = nod("eyes", "calibrate", "--out", str(out), "--set", "left_pan=1,left_pan=2")
    assert res.returncode == 2 and "twice" in one_line_error(res.stderr)
    assert not out.exists()
