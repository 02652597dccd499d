"""Bench-testing real drivers with the sim participant: `nod run --sim --eyes-driver maestro`."""

import subprocess
import sys

import pytest

from tests.emulators.maestro_emulator import SET_TARGET, MaestroEmulator

from .conftest import ROOT, free_port

pytestmark = pytest.mark.integration


def _set_targets(raw: bytes, channel: int) -> list[float]:
    """Every Set Target pulse (µs) the driver sent to one channel, in order."""
    out, i = [], 0
    while i + 3 < len(raw):
        if raw[i] == SET_TARGET and raw[i + 1] == channel:
            out.append((raw[i + 2] | raw[i + 3] << 7) / 4.0)
            i += 4
        else:
            i += 1
    return out


def test_a_session_drives_a_maestro_over_a_serial_port(tmp_path):
    with MaestroEmulator(link_dir=tmp_path) as emu:
        run = subprocess.run(
            [
                sys.executable,
                "-m",
                "services.cli",
                "run",
                "--sim",
                # 4x: each trial's gaze is held ≈ 0.5 s of wall time, long enough for the eyes'
                # loop on a loaded host to send it (at 8x a busy host once skipped one level)
                "--speed",
                "4",
                "--db",
                str(tmp_path / "s.sqlite"),
                "--listen",
                f"tcp/127.0.0.1:{free_port()}",
                "--stale-ms",
                "2000",
                "--eyes-driver",
                "maestro",
                "--eyes-port",
                emu.port,
            ],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert run.returncode == 0, run.stdout + run.stderr
        pulses = _set_targets(bytes(emu.received), channel=0)  # left pan
    distinct = []
    for p in pulses:
        if not distinct or distinct[-1] != p:
            distinct.append(p)
    # neutral, the attention gesture's limit, and five gaze levels toward alternating sides
    eyes_log = next(iter(sorted(tmp_path.glob("*.logs/*/eyes.log"))), None)
    context = f"{distinct}\n{run.stdout}\n{eyes_log.read_text()[-4000:] if eyes_log else ''}"
    assert len(set(distinct)) >= 7, context
    assert all(500.0 <= p <= 2500.0 for p in pulses)
    assert distinct[-1] == pytest.approx(1500.0, abs=1.0)  # neutral when the session ends
    left = [p for p in distinct if p < 1499]
    right = [p for p in distinct if p > 1501]
    assert len(left) >= 2 and len(right) >= 3  # blue trials 4, 7 one way; red 5, 6, 8 the other
