"""The eyes' bench tools beside a running `nod eyes` service, on a Maestro emulator."""

from __future__ import annotations

from functools import partial

import pytest

from services.eyes.trims import load_trims
from tests.emulators.maestro_emulator import MaestroEmulator
from tests.polling import eventually
from tests.processes import run_nod

pytestmark = pytest.mark.integration

EYES_TOML = """
[calibration.left_pan]
min_deg = 10.0
max_deg = 170.0
[maestro.link]
timeout_s = 0.5
"""


nod = partial(run_nod, timeout=30)


def test_the_service_loads_calibrated_trims_and_owns_the_port(router, spawn, tmp_path):
    eyes = tmp_path / "eyes.toml"
    eyes.write_text(EYES_TOML)
    trims = tmp_path / "eyes_trims.toml"
    with MaestroEmulator(link_dir=tmp_path) as emu:
        hw = ["--driver", "maestro", "--port", emu.port, "--eyes-config", str(eyes)]
        res = nod("eyes", "calibrate", *hw, "--out", str(trims), "--set", "left_pan=4,right_pan=-2")
        assert res.returncode == 0, res.stderr
        assert load_trims(trims).as_dict() == {
            "left_pan": 4.0,
            "left_tilt": 0.0,
            "right_pan": -2.0,
            "right_tilt": 0.0,
        }
        emu.channels[0].target = emu.channels[2].target = 6000  # forget the tool's last targets

        proc = spawn("eyes", *hw, "--trims", str(trims))
        # neutral through the trims: 90° + trim on each pan servo, 500–2500 µs over 0–180°
        want = (500 + 94 / 180 * 2000, 1500.0, 500 + 88 / 180 * 2000, 1500.0)
        quarter = tuple(round(p * 4) / 4 for p in want)
        assert eventually(lambda: emu.targets_us() == quarter, 15.0), emu.targets_us()
        assert proc.poll() is None

        res = nod("eyes", "point", "--yaw", "0.3", *hw)
        assert res.returncode == 2
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and "held by another program" in lines[0], res.stderr
        assert emu.targets_us() == quarter  # the service's neutral stands


def test_the_service_refuses_a_bad_trims_file_in_one_line(spawn, tmp_path):
    trims = tmp_path / "eyes_trims.toml"
    trims.write_text("[trim_deg]\nleft_pan = 12.0\nright_tilt = 99.0\n")
    proc = spawn("eyes", "--trims", str(trims))
    assert proc.wait(30) == 2
    text = proc.log_path.read_text()  # refused before any Zenoh session is opened
    assert "Traceback" not in text and len(text.strip().splitlines()) == 1
    assert "right_tilt = 99.0: a trim must be a number within ±20°" in text
