"""The rig file: what it accepts, the one line it gives for what it does not, the commands."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from services.core.rigfile import RigFileError, identity, load_rig, split_endpoint
from services.launch.commands import command

GOOD = """
[rig]
name = "lab2"
router = "tcp/10.0.0.1:7447"
params = "p.toml"
[hosts.control]
router = true
services = ["monitor"]
[hosts.cam]
services = ["vision"]
[hosts.arm]
role = "arm"
services = ["decision", "actuation", "eyes"]
[vision]
source = "rtsp://cam/stream"
tracker = "mediapipe"
calibration = "table.toml"
[actuation]
driver = "feetech"
port = "/dev/ttyUSB0"
config = "/etc/nod/arm.toml"
stale_ms = 300
[eyes]
driver = "arduino"
port = "/dev/ttyACM0"
trims = "trims.toml"
[monitor]
args = ["--serve-web"]
"""


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "rig.toml"
    p.write_text(text)
    return p


def test_a_good_rig_file(tmp_path: Path) -> None:
    rig = load_rig(write(tmp_path, GOOD))
    assert rig.name == "lab2" and rig.router == "tcp/10.0.0.1:7447"
    assert rig.params == tmp_path / "p.toml"  # relative to the rig file
    assert rig.host_of("actuation").name == "arm" and rig.router_host().name == "control"
    act = command(rig, "actuation")
    # -P: the working directory is not on the child's sys.path (tests/integration/
    # test_child_isolation.py starts one from a folder with a poisoned serial.py and zenoh.py).
    assert act[:5] == [sys.executable, "-P", "-m", "services.cli", "actuation"]
    assert act[act.index("--connect") + 1] == "tcp/10.0.0.1:7447"
    assert act[act.index("--port") + 1] == "/dev/ttyUSB0"
    assert act[act.index("--arm-config") + 1] == "/etc/nod/arm.toml"  # absolute stays
    assert act[act.index("--stale-ms") + 1] == "300.0"
    eyes = command(rig, "eyes")
    assert eyes[eyes.index("--trims") + 1] == str(tmp_path / "trims.toml")
    vision = command(rig, "vision")
    assert vision[vision.index("--source") + 1] == "rtsp://cam/stream"
    assert vision[vision.index("--calibration") + 1] == str(tmp_path / "table.toml")
    assert command(rig, "monitor")[-1] == "--serve-web"
    assert "--params" not in command(rig, "monitor")
    # Simulated hardware: no devices, the sim participant in place of the camera.
    sim = command(rig, "actuation", sim_hardware=True, connect="tcp/127.0.0.1:9")
    assert sim[sim.index("--driver") + 1] == "sim" and "--port" not in sim
    assert sim[sim.index("--connect") + 1] == "tcp/127.0.0.1:9"
    assert command(rig, "vision", sim_hardware=True)[4] == "sim"


def test_tls_rigs_use_each_host_identity(tmp_path: Path) -> None:
    rig = load_rig(write(tmp_path, GOOD.replace('params = "p.toml"', 'tls = "/etc/nod/tls"')))
    cmd = command(rig, "decision")
    assert cmd[cmd.index("--config") + 1] == "/etc/nod/tls/arm/zenoh.json5"
    assert "--connect" not in cmd
    # The monitor runs with the read-only identity, not its host's (control) one.
    mon = command(rig, "monitor")
    assert mon[mon.index("--config") + 1] == "/etc/nod/tls/monitor/zenoh.json5"
    # `nod up` itself: the host's launcher identity, the only one that may put rig/event.
    launcher = identity(rig, "launcher", rig.hosts["arm"])
    assert launcher == Path("/etc/nod/tls/arm/launcher/zenoh.json5")
    assert identity(rig, "monitor") == Path("/etc/nod/tls/monitor/zenoh.json5")


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (("[rig]", "[rigg]"), "rigg: unknown table"),
        (('name = "lab2"', 'name = "lab 2"'), "rig.name"),
        (('router = "tcp/10.0.0.1:7447"', "router = 7447"), "rig.router"),
        (('services = ["monitor"]', 'services = ["monitor", "decision"]'), "already runs"),
        (('services = ["vision"]', 'services = ["camera"]'), "unknown service 'camera'"),
        (('[hosts.cam]', '[hosts.cam]\nrouter = true'), "only one host may run the router"),
        (('tracker = "mediapipe"', 'tracker = "yolo"'), "vision.tracker"),
        (('driver = "feetech"', 'driver = "dynamixel"'), "actuation.driver"),
        (('port = "/dev/ttyUSB0"\n', ""), "actuation.port"),
        (('stale_ms = 300', 'stale = 300'), "actuation.stale: unknown key"),
        (('args = ["--serve-web"]', 'args = "--serve-web"'), "monitor.args"),
        (('role = "arm"', 'role = "arm"\ncolour = "red"'), "hosts.arm.colour"),
        # Values the services would refuse only once started (then restarted until given up):
        (("stale_ms = 300", "stale_ms = -4"), r"actuation.stale_ms: must be in \(0, 10000\] ms"),
        (("stale_ms = 300", "stale_ms = 1e9"), "actuation.stale_ms"),
        (("stale_ms = 300", 'stale_ms = "fast"'), "actuation.stale_ms: must be a number"),
        (("stale_ms = 300", "stale_ms = true"), "actuation.stale_ms: must be a number"),
        (('trims = "trims.toml"', 'trims = "trims.toml"\nstale_ms = nan'), "eyes.stale_ms"),
        (("args = [\"--serve-web\"]", 'args = ["--serve-web"]\n[sim]\nseed = -1'), "sim.seed"),
        (("args = [\"--serve-web\"]", 'args = ["--serve-web"]\n[sim]\nseed = 1.5'), "sim.seed"),
        (('port = "/dev/ttyUSB0"', "port = 0"), "actuation.port: must be a string"),
        (('router = "tcp/10.0.0.1:7447"', 'router = "tcp/10.0.0.1:99999"'), "rig.router"),
        (('router = "tcp/10.0.0.1:7447"', 'router = "tcp/10.0.0.1"'), "rig.router"),
    ],
)
def test_bad_rig_files_say_which_key(tmp_path: Path, change: tuple[str, str], message: str) -> None:
    old, new = change
    assert old in GOOD
    with pytest.raises(RigFileError, match=message) as info:
        load_rig(write(tmp_path, GOOD.replace(old, new, 1)))
    assert "\n" not in str(info.value) and str(tmp_path) in str(info.value)


def test_unreadable_and_malformed_files(tmp_path: Path) -> None:
    with pytest.raises(RigFileError, match="cannot read"):
        load_rig(tmp_path / "missing.toml")
    with pytest.raises(RigFileError, match="not valid TOML"):
        load_rig(write(tmp_path, "[rig\nname="))


def test_the_rig_file_accepts_exactly_what_the_services_accept() -> None:
    from services.actuation.drivers import ARM_DRIVERS
    from services.core import rigfile
    from services.eyes.drivers import EYES_DRIVERS
    from services.speaker.drivers import DRIVERS as SPEAKER_DRIVERS
    from services.vision.trackers import TRACKERS

    assert rigfile.ARM_DRIVERS == ARM_DRIVERS
    assert rigfile.EYES_DRIVERS == EYES_DRIVERS
    assert set(rigfile.TRACKERS) == set(TRACKERS)
    assert rigfile.SPEAKER_DRIVERS == SPEAKER_DRIVERS


def test_endpoints_split_into_scheme_host_and_port() -> None:
    assert split_endpoint("tls/192.168.10.1:7447") == ("tls", "192.168.10.1", 7447)
    assert split_endpoint("tcp/[::1]:7500#iface=lo") == ("tcp", "::1", 7500)
    assert split_endpoint("tls/control.lab:7447?rel=1") == ("tls", "control.lab", 7447)
    for bad in ("192.168.10.1:7447", "tcp/host", "tcp/host:0", "tcp/host:65536", "tcp/h:x"):
        with pytest.raises(ValueError):
            split_endpoint(bad)


def test_a_rig_may_place_the_speaker_and_its_wav_file_is_relative_to_the_rig(
    tmp_path: Path,
) -> None:
    text = GOOD.replace('services = ["monitor"]', 'services = ["monitor", "speaker"]')
    rig = load_rig(write(tmp_path, text + '[speaker]\ndriver = "wav"\nout = "cues.wav"\n'))
    cmd = command(rig, "speaker")
    assert cmd[cmd.index("--driver") + 1 :][:3] == ["wav", "--out", str(tmp_path / "cues.wav")]
    assert "speaker" not in rig.required  # a trial runs without its cue
    assert command(rig, "speaker", sim_hardware=True)[-2:] == ["--driver", "sim"]
    with pytest.raises(RigFileError, match="speaker.out"):
        load_rig(write(tmp_path, text + '[speaker]\ndriver = "wav"\n'))
    with pytest.raises(RigFileError, match="speaker.driver"):
        load_rig(write(tmp_path, text + '[speaker]\ndriver = "alsa"\n'))


def test_a_rig_may_place_the_display_on_its_http_address(tmp_path: Path) -> None:
    text = GOOD.replace('services = ["monitor"]', 'services = ["monitor", "display"]')
    rig = load_rig(write(tmp_path, text + '[display]\nhttp = "0.0.0.0:8090"\n'))
    cmd = command(rig, "display")
    assert cmd[cmd.index("--http") + 1] == "0.0.0.0:8090"
    assert "display" not in rig.required  # a trial runs without the participant's screen
    assert "--http" not in command(load_rig(write(tmp_path, text)), "display")  # its default
    for bad in ('"8090"', '"host:99999"', "8090", '":8090"'):
        with pytest.raises(RigFileError, match="display.http"):
            load_rig(write(tmp_path, text + f"[display]\nhttp = {bad}\n"))


def test_a_rig_may_place_the_lsl_outlet(tmp_path: Path) -> None:
    text = GOOD.replace('services = ["monitor"]', 'services = ["monitor", "lsl"]')
    rig = load_rig(write(tmp_path, text + '[lsl]\nargs = ["-v"]\n'))
    assert command(rig, "lsl")[-1] == "-v" and "lsl" not in rig.required
    with pytest.raises(RigFileError, match="lsl.rate"):
        load_rig(write(tmp_path, text + "[lsl]\nrate = 100\n"))


def test_nod_experiment_next_takes_the_rig_file(tmp_path: Path) -> None:
    """`nod experiment next --rig-file`: the rig and its router, or the control's identity."""
    from services.tools import operator

    path = write(tmp_path, GOOD)
    assert operator.rig_file_flags(path) == ["--connect", "tcp/10.0.0.1:7447", "--rig", "lab2"]
    assert operator.rig_file_flags(path, explicit=True) == ["--rig", "lab2"]
    tls = write(tmp_path, GOOD.replace('params = "p.toml"', 'tls = "/etc/nod/tls"'))
    assert operator.rig_file_flags(tls)[:2] == ["--config", "/etc/nod/tls/control/zenoh.json5"]
    assert operator.build_parser("next").parse_args(["--rig-file", str(path)]).rig_file == path
