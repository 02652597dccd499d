"""A rig file's paths are relative to it, and a copy made as docs/rig.md says works.

Every path key resolves against the rig file's folder, whatever the working directory; `nod up
deploy/rig.example.toml --init-rig DIR` copies the example with the files it names, and the copy
passes the preflight. The example copied alone (what the README used to suggest) names files
that are not beside it, and the preflight says which.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from services.core.rigfile import FILE_KEYS, FOLDER_KEYS, RigFileError, is_file_source, load_rig
from services.launch import up
from services.launch.commands import command
from services.vision.capture import parse_source

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "deploy" / "rig.example.toml"
DEVICES = {"actuation.port", "eyes.port", "vision.source (camera 0)"}

EVERY_PATH = """
[rig]
router = "tcp/127.0.0.1:7447"
params = "p.toml"
tls = "tls"
[hosts.arm]
services = ["decision", "actuation", "eyes", "vision"]
[vision]
source = "clips/table.mp4"
calibration = "table.toml"
[actuation]
config = "hw/arm.toml"
state_dir = "state"
[eyes]
config = "hw/eyes.toml"
trims = "~/trims.toml"
state_dir = "/var/lib/nod/state"
"""


def test_every_path_key_is_relative_to_the_rig_file(tmp_path: Path, monkeypatch) -> None:
    folder = tmp_path / "etc"
    folder.mkdir()
    (folder / "rig.toml").write_text(EVERY_PATH)
    monkeypatch.chdir(tmp_path)  # read by a relative name, from elsewhere
    rig = load_rig(Path("etc/rig.toml"))
    assert rig.params == folder / "p.toml" and rig.tls == folder / "tls"
    got = {f"{s}.{k}": rig.sections[s][k] for s, k in (*FILE_KEYS, *FOLDER_KEYS) if s != "rig"}
    assert got == {
        "actuation.config": folder / "hw/arm.toml", "eyes.config": folder / "hw/eyes.toml",
        "eyes.trims": Path.home() / "trims.toml", "vision.calibration": folder / "table.toml",
        "actuation.state_dir": folder / "state", "eyes.state_dir": Path("/var/lib/nod/state"),
    }
    vision = command(rig, "vision")
    assert vision[vision.index("--source") + 1] == str(folder / "clips/table.mp4")
    for other in ("0", "sim", "zenoh:sim/camera", "rtsp://cam/stream", "/dev/video2"):
        (folder / "rig.toml").write_text(EVERY_PATH.replace("clips/table.mp4", other))
        assert load_rig(folder / "rig.toml").sections["vision"]["source"] == other


@pytest.mark.parametrize(
    "source", ["0", "12", "sim", "zenoh:sim/camera", "rtsp://cam/s", "http://x/y.mjpg",
               "table.mp4", "clips/a b.avi", "/dev/video0", "sim.mp4", " 3 "],
)
def test_the_rig_file_tells_a_file_source_as_vision_does(source: str) -> None:
    assert is_file_source(source) == (parse_source(source).kind == "file")


def test_the_example_copied_with_init_rig_passes_the_preflight(tmp_path: Path, capsys) -> None:
    folder = tmp_path / "etc" / "nod"
    assert up.main([str(EXAMPLE), "--init-rig", str(folder)]) == 0
    out = capsys.readouterr().out
    assert f"wrote {folder / 'rig.toml'}" in out
    assert (folder / "rig.toml").read_text() == EXAMPLE.read_text()  # comments and all
    for name in ("params.example.toml", "hardware/arm.example.toml", "hardware/eyes.example.toml"):
        assert (folder / name).read_bytes() == (EXAMPLE.parent / name).read_bytes()
    rig = str(folder / "rig.toml")
    assert up.main([rig, "--dry-run", "--sim-hardware"]) == 0  # every file it names is there
    assert capsys.readouterr().err == ""
    # With the real devices, only the devices themselves can be missing on a test machine.
    code = up.main([rig, "--dry-run"])
    lines = capsys.readouterr().err.splitlines()
    keys = {ln.removeprefix("nod up: ").split(": ")[0] for ln in lines}
    assert keys <= DEVICES and code == (2 if keys else 0), keys
    # Once is enough: the lab's rig file is never overwritten.
    assert up.main([str(EXAMPLE), "--init-rig", str(folder)]) == 2
    assert "exists: not overwritten" in capsys.readouterr().err


def test_the_example_copied_alone_names_files_that_are_not_there(tmp_path: Path, capsys) -> None:
    shutil.copyfile(EXAMPLE, tmp_path / "rig.toml")
    code = up.main([str(tmp_path / "rig.toml"), "--dry-run", "--sim-hardware"])
    err = capsys.readouterr().err
    assert code == 2 and str(tmp_path / "params.example.toml") in err, err


def test_init_rig_keeps_absolute_paths_and_refuses_to_leave_the_folder(tmp_path: Path) -> None:
    from services.launch.init_rig import init_rig

    src = tmp_path / "src"
    src.mkdir()
    (src / "p.toml").write_text("")
    arm = tmp_path / "arm.toml"
    arm.write_text("")
    text = (f'[rig]\nrouter = "tcp/127.0.0.1:7447"\nparams = "p.toml"\n[hosts.a]\n'
            f'services = ["actuation"]\n[actuation]\nconfig = "{arm}"\n')
    (src / "rig.toml").write_text(text)
    lines = init_rig(src / "rig.toml", tmp_path / "out")
    assert (tmp_path / "out" / "p.toml").exists() and len(lines) == 3, lines  # wrote, copied, next
    (src / "rig.toml").write_text(text.replace(f'"{arm}"', '"../arm.toml"'))
    with pytest.raises(RigFileError, match="actuation.config.*leads out of the rig file's folder"):
        init_rig(src / "rig.toml", tmp_path / "out2")
    assert not (tmp_path / "out2").exists()
