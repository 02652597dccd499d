"""`nod up --dry-run` checks every file, serial port and camera the rig names, one line each.

A rig of real drivers on pseudo-terminals (a pty is a character device, as a USB serial port
is), a video file for the camera, the example hardware files, a trims file, a calibration and
`nod lab secure` identities: it passes. Each fault is one line naming its key, exit 2; several
are one line each.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from services.eyes.trims import EyesTrims, trims_toml
from services.launch import up
from services.model.geometry import TableLayout
from services.vision.calibration import dump_calibration

ROOT = Path(__file__).resolve().parents[2]
HARDWARE = ROOT / "deploy" / "hardware"


def rig_text(arm_port: str, eyes_port: str) -> str:
    return f"""
[rig]
name = "rig1"
router = "tcp/127.0.0.1:7447"
params = "params.toml"
[hosts.control]
router = true
services = ["monitor"]
[hosts.camera]
services = ["vision"]
[hosts.arm]
services = ["decision", "actuation", "eyes"]
[vision]
source = "table.avi"
tracker = "aruco"
calibration = "table.toml"
[actuation]
driver = "feetech"
port = "{arm_port}"
config = "hardware/arm.toml"
state_dir = "state"
[eyes]
driver = "maestro"
port = "{eyes_port}"
config = "hardware/eyes.toml"
trims = "trims.toml"
"""


@pytest.fixture
def ptys() -> Iterator[tuple[str, str]]:
    """Two pseudo-terminals: the arm's and the eyes' serial ports."""
    fds = [os.openpty() for _ in range(2)]
    try:
        yield os.ttyname(fds[0][1]), os.ttyname(fds[1][1])
    finally:
        for pair in fds:
            for fd in pair:
                os.close(fd)


@pytest.fixture
def rig(tmp_path: Path, ptys: tuple[str, str]) -> Path:
    """A good rig file with every file it names, beside it."""
    (tmp_path / "hardware").mkdir()
    shutil.copyfile(HARDWARE / "arm.example.toml", tmp_path / "hardware" / "arm.toml")
    shutil.copyfile(HARDWARE / "eyes.example.toml", tmp_path / "hardware" / "eyes.toml")
    (tmp_path / "params.toml").write_text("")
    (tmp_path / "trims.toml").write_text(trims_toml(EyesTrims(left_pan=1.5)))
    (tmp_path / "table.toml").write_text(dump_calibration(TableLayout()))
    video = cv2.VideoWriter(
        str(tmp_path / "table.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48)
    )
    for _ in range(3):
        video.write(np.zeros((48, 64, 3), np.uint8))
    video.release()
    path = tmp_path / "rig.toml"
    path.write_text(rig_text(*ptys))
    return path


def dry_run(rig: Path, capsys, *extra: str) -> tuple[int, list[str]]:
    code = up.main([str(rig), "--dry-run", *extra])
    return code, capsys.readouterr().err.splitlines()


def test_a_good_rig_passes(rig: Path, capsys) -> None:
    assert dry_run(rig, capsys) == (0, [])
    for host in ("control", "camera", "arm"):
        assert dry_run(rig, capsys, "--host", host) == (0, [])


def _edit(rig: Path, old: str, new: str) -> None:
    text = rig.read_text()
    assert old in text, old
    rig.write_text(text.replace(old, new))


@pytest.mark.parametrize(
    ("fault", "key", "why"),
    [
        (lambda d: (d / "hardware" / "arm.toml").unlink(), "actuation.config", "does not exist"),
        (lambda d: (d / "hardware" / "arm.toml").write_text("speed = 3\n"), "actuation.config",
         "unknown key"),
        (lambda d: (d / "hardware" / "eyes.toml").write_text("[maestro\n"), "eyes.config",
         "not valid TOML"),
        (lambda d: (d / "trims.toml").write_text("[trim_deg]\nleft_pan = 90.0\n"), "eyes.trims",
         "left_pan"),
        (lambda d: (d / "trims.toml").write_text("x = 1\n"), "eyes.trims", "trim_deg"),
        (lambda d: (d / "table.toml").write_text("[red]\nx1 = 'a'\n"), "vision.calibration",
         "x1"),
        (lambda d: (d / "table.toml").chmod(0), "vision.calibration", "not readable"),
        (lambda d: (d / "table.avi").unlink(), "vision.source", "does not exist"),
        (lambda d: (d / "table.avi").write_text("not a video"), "vision.source",
         "not a video"),
        (lambda d: _edit(d / "rig.toml", 'source = "table.avi"', 'source = "37"'),
         "vision.source (camera 37)", "/dev/video37 does not exist"),
        (lambda d: _edit(d / "rig.toml", 'source = "table.avi"', 'source = "/dev/shm"'),
         "vision.source", "/dev/shm is not a device"),
        (lambda d: _edit(d / "rig.toml", 'port = "/dev/pts', 'port = "/dev/ptsX'),
         "actuation.port", "does not exist"),
        (lambda d: _edit(d / "rig.toml", 'port = "/dev/pts', 'port = "/dev/ptsX'),
         "eyes.port", "does not exist"),
        (lambda d: _edit(d / "rig.toml", 'config = "hardware/arm.toml"\n', ""),
         "actuation.config", "needs an arm file"),
        (lambda d: (d / "state").write_text(""), "actuation.state_dir", "is not a folder"),
    ],
)
def test_each_problem_is_one_line_naming_the_key(
    rig: Path, capsys, fault, key: str, why: str
) -> None:
    if os.geteuid() == 0 and why.startswith("not readable"):
        pytest.skip("root reads every file")
    fault(rig.parent)
    code, lines = dry_run(rig, capsys)
    assert code == 2
    named = [ln for ln in lines if ln.startswith(f"nod up: {key}: ")]
    assert len(named) == 1 and why in named[0], lines
    print(f"\n{named[0]}")


def test_a_port_that_is_not_a_device(rig: Path, capsys) -> None:
    (rig.parent / "ttyFAKE").write_text("")
    text = rig.read_text()
    arm_port = text.split('port = "')[1].split('"')[0]
    rig.write_text(text.replace(arm_port, str(rig.parent / "ttyFAKE"), 1))
    code, lines = dry_run(rig, capsys)
    assert code == 2 and lines == [
        f"nod up: actuation.port: {rig.parent / 'ttyFAKE'} is not a device (a character device "
        "such as /dev/ttyUSB0)"
    ]


def test_every_problem_at_once_one_line_each(rig: Path, capsys) -> None:
    d = rig.parent
    for name in ("hardware/arm.toml", "hardware/eyes.toml", "trims.toml", "table.toml",
                 "table.avi"):
        (d / name).unlink()
    _edit(rig, 'port = "/dev/pts', 'port = "/dev/ptsX')
    code, lines = dry_run(rig, capsys)
    keys = sorted(ln.removeprefix("nod up: ").split(": ")[0] for ln in lines)
    assert code == 2
    assert keys == sorted([
        "actuation.config", "actuation.port", "eyes.config", "eyes.port", "eyes.trims",
        "vision.calibration", "vision.source",
    ]), lines


def test_sim_hardware_needs_no_device_and_no_trims(rig: Path, capsys) -> None:
    d = rig.parent
    (d / "trims.toml").unlink()
    (d / "table.avi").unlink()
    _edit(rig, 'port = "/dev/pts', 'port = "/dev/ptsX')
    assert dry_run(rig, capsys, "--sim-hardware") == (0, [])
    (d / "hardware" / "eyes.toml").unlink()  # the eyes service reads it even simulated
    code, lines = dry_run(rig, capsys, "--sim-hardware")
    assert code == 2 and len(lines) == 1 and lines[0].startswith("nod up: eyes.config: ")


def test_tls_identities_and_their_certificates(rig: Path, capsys) -> None:
    from services.lab.secure import secure

    tls = rig.parent / "tls"
    secure(tls, ["control", "camera", "arm"], "rig1", "127.0.0.1", 7447, 30, tls)
    _edit(rig, 'params = "params.toml"', 'params = "params.toml"\ntls = "tls"')
    assert dry_run(rig, capsys, "--host", "arm") == (0, [])
    assert dry_run(rig, capsys) == (0, [])  # the router's config and the monitor's identity too
    (tls / "arm" / "launcher" / "zenoh.json5").unlink()
    (tls / "arm" / "key.pem").write_text("-----BEGIN PRIVATE KEY-----\nnope\n")
    code, lines = dry_run(rig, capsys, "--host", "arm")
    assert code == 2 and len(lines) == 2, lines
    assert all(ln.startswith("nod up: rig.tls (") for ln in lines), lines
    assert any("nod up's identity" in ln and "does not exist" in ln for ln in lines), lines
    assert any(f"{tls / 'arm' / 'key.pem'} is not a PEM private key" in ln for ln in lines)
    (tls / "control" / "router.json5").write_text("{ mode: ")
    code, lines = dry_run(rig, capsys, "--host", "control")
    assert code == 2 and lines[0].startswith("nod up: rig.tls (the router's config): ")
    assert "is not a zenoh config" in lines[0], lines


def test_the_speaker_needs_its_wav_folder_or_its_sound_library(rig: Path, capsys) -> None:
    _edit(rig, 'services = ["monitor"]', 'services = ["monitor", "speaker"]')
    text = rig.read_text()
    rig.write_text(text + '[speaker]\ndriver = "wav"\nout = "audio/cues.wav"\n')
    code, lines = dry_run(rig, capsys)
    assert code == 2 and any(ln.startswith("nod up: speaker.out: ") and "audio does not exist"
                             in ln for ln in lines), lines
    (rig.parent / "audio").mkdir()
    assert dry_run(rig, capsys) == (0, [])
    rig.write_text(text + '[speaker]\ndriver = "sounddevice"\n')
    if importlib.util.find_spec("sounddevice") is None:  # not installed (as in CI)
        code, lines = dry_run(rig, capsys)
        assert code == 2 and lines == [
            "nod up: speaker.driver: the sounddevice driver needs the audio extra: pip install "
            "'nod-hri[audio]' (and PortAudio: apt install libportaudio2)"
        ]
    assert dry_run(rig, capsys, "--sim-hardware") == (0, [])


def test_the_lsl_outlet_needs_pylsl(rig: Path, capsys, monkeypatch) -> None:
    _edit(rig, 'services = ["monitor"]', 'services = ["monitor", "lsl"]')
    assert dry_run(rig, capsys) == (0, [])  # installed here (the test extra has it)
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "pylsl" else real(name, *a))
    assert dry_run(rig, capsys) == (
        2, ["nod up: lsl: the LSL outlet needs the lsl extra: pip install 'nod-hri[lsl]'"])


def test_the_display_needs_an_address_it_can_serve_on(rig: Path, capsys) -> None:
    import socket

    _edit(rig, 'services = ["monitor"]', 'services = ["monitor", "display"]')
    text = rig.read_text()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        rig.write_text(text + f'[display]\nhttp = "127.0.0.1:{port}"\n')
        code, lines = dry_run(rig, capsys)
        assert code == 2 and lines == [
            f"nod up: display.http: cannot serve on 127.0.0.1:{port}: Address already in use "
            "(a display already running, or another server)"], lines
    assert dry_run(rig, capsys) == (0, [])  # free again
    rig.write_text(text + '[display]\nhttp = "192.0.2.1:8090"\n')  # not an address of this host
    code, lines = dry_run(rig, capsys)
    assert code == 2 and lines[0].startswith("nod up: display.http: cannot serve on 192.0.2.1")


def test_the_dry_run_names_the_router_and_what_sim_hardware_replaces(rig: Path, capsys) -> None:
    assert up.main([str(rig), "--dry-run"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "router: in this process, listening on tcp/127.0.0.1:7447" in out
    assert up.main([str(rig), "--dry-run", "--host", "arm"]) == 0
    assert "router: at tcp/127.0.0.1:7447 (run by control, not here)" in capsys.readouterr().out
    _edit(rig, "[eyes]", '[speaker]\ndriver = "wav"\nout = "cues"\n[eyes]')
    _edit(rig, 'services = ["monitor"]', 'services = ["monitor", "speaker"]')
    assert up.main([str(rig), "--dry-run", "--sim-hardware"]) == 0
    said = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("--sim-hardware")]
    assert len(said) == 1 and "speaker driver 'wav' runs as 'sim' (no WAV written)" in said[0]
    assert "actuation driver 'feetech' runs as 'sim'" in said[0]
