"""Services start isolated from the working directory: a stray module there shadows nothing.

`nod up`, `nod run` and the systemd units start every child as `python -P -m services.cli …`
(`services.core.lifeline.nod_command`). Here the working directory holds a `serial.py`, a
`zenoh.py` and a `services/` package that abort on import; every command builder's child starts
from it all the same, and so does the `nod` console script.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from services.core.keys import Keys
from services.core.rigfile import load_rig
from services.launch.commands import command
from services.launch.up import router_command
from services.run import build_parser, child_command

from .conftest import wait_for

pytestmark = pytest.mark.integration
POISON = 'raise SystemExit("POISONED: {name} was imported from the working directory")\n'


@pytest.fixture
def poisoned(tmp_path: Path) -> Path:
    """A working directory whose modules would replace pyserial, zenoh and the project."""
    cwd = tmp_path / "cwd"
    (cwd / "services").mkdir(parents=True)
    for name in ("serial.py", "zenoh.py", "services/__init__.py"):
        (cwd / name).write_text(POISON.format(name=name))
    return cwd


def rig_file(tmp_path: Path, endpoint: str) -> Path:
    path = tmp_path / "rig.toml"
    path.write_text(
        f'[rig]\nname = "iso"\nrouter = "{endpoint}"\n'
        '[hosts.here]\nrouter = true\nservices = ["decision", "actuation"]\n'
    )
    return path


def run(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=60)


def test_the_poison_is_real_without_isolation(poisoned: Path) -> None:
    """A command line without -P imports the working directory's modules."""
    plain = run([sys.executable, "-m", "services.cli", "actuation", "--help"], poisoned)
    assert plain.returncode != 0 and "POISONED" in plain.stderr


def test_every_command_builder_starts_its_child_from_a_poisoned_folder(
    poisoned: Path, tmp_path: Path, endpoint: str
) -> None:
    rig = load_rig(rig_file(tmp_path, endpoint))
    args = build_parser().parse_args(["--sim", "--listen", endpoint])
    builders = {
        "nod up: actuation (imports pyserial and zenoh)": command(rig, "actuation"),
        "nod up: the router": router_command(rig),
        "nod run: decision": child_command("decision", args, epoch_ns=0),
        "the nod console script": [str(Path(sys.executable).with_name("nod")), "eyes"],
    }
    for what, argv in builders.items():
        done = run([*argv, "--help"], poisoned)
        assert done.returncode == 0 and "POISONED" not in done.stderr, (what, done.stderr)
        assert "usage:" in done.stdout, what


def test_a_service_from_a_poisoned_folder_joins_the_rig(
    poisoned: Path, tmp_path: Path, endpoint: str, router
) -> None:
    rig = load_rig(rig_file(tmp_path, endpoint))
    log = (tmp_path / "decision.log").open("w")
    t0 = time.monotonic()
    proc = subprocess.Popen(
        command(rig, "decision"), cwd=poisoned, stdout=log, stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
    )
    try:
        alive = Keys("iso").alive("decision")

        def up_or_dead() -> bool:
            if proc.poll() is not None:
                return True
            return bool(list(router.liveliness().get(alive, timeout=1)))

        wait_for(up_or_dead, 30, "decision's liveliness token")
        assert proc.poll() is None, (tmp_path / "decision.log").read_text()[-2000:]
        print(f"\ndecision started from a poisoned folder, alive in {time.monotonic() - t0:.2f} s")
    finally:
        proc.terminate()
        proc.wait(10)
    assert "POISONED" not in (tmp_path / "decision.log").read_text()
