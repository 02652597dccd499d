"""An emulated serial device in a process of its own, for tests that time a driver against it.

In the test's own process the emulator's thread shares the GIL with the test's subscribers: on a
loaded machine the scheduler preempts a thread that holds the GIL, and the emulator then waits
for it, tens of milliseconds at times (an inversion the emulator thread's own priority cannot
cure), past the 50 ms reply timeout of a driver's fast link. A real device answers from its own
silicon; a process of its own at nice -10, like the drivers it answers, is the nearest a test
machine gets.

    with DeviceProcess("feetech", tmp_path) as bus:   # or "maestro"
        ... bus.port ...; bus.silent = True; bus.unplug(); bus.replug()

The child reads one command a line on stdin and answers "ok" once it is done, so a fault is in
place when the call returns: `silent 1|0`, `unplug`, `replug`, `silent S` and `unplugged S`
(the fault for S seconds, then healthy again), `quit`.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import threading
from pathlib import Path

from services.model.device import Scoped
from tests.emulators.feetech_emulator import IDS, FeetechBusEmulator
from tests.emulators.maestro_emulator import MaestroEmulator
from tests.emulators.pty_device import PtyDevice

ROOT = Path(__file__).resolve().parents[2]
KINDS = ("feetech", "maestro")


class DeviceProcess(Scoped):
    """The parent's handle: the port to open, and the faults to inject."""

    def __init__(self, kind: str, link_dir: Path) -> None:
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
        self.kind, self.link_dir = kind, Path(link_dir)
        self.port = ""
        self._silent = False
        self._proc: subprocess.Popen[str] | None = None

    def _on_enter(self) -> None:
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "tests.emulators.own_process", self.kind, str(self.link_dir)],
            cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
        )
        self.port = self._reply().removeprefix("port ")

    def _on_exit(self) -> None:
        proc = self._proc
        if proc is None:
            return
        with contextlib.suppress(OSError, RuntimeError):
            self._say("quit")
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
        self._proc = None

    @property
    def silent(self) -> bool:
        """Whether the device swallows requests (set: the child applies it before returning)."""
        return self._silent

    @silent.setter
    def silent(self, value: bool) -> None:
        self._say(f"silent {int(value)}")
        self._silent = value

    def unplug(self) -> None:
        """Pull the cable (the port path disappears)."""
        self._say("unplug")

    def fault_for(self, fault: str, seconds: float) -> None:
        """`silent` or `unplugged` for `seconds`, then healthy again, timed by the device itself.

        A test that restores the device only once it has seen the trial interrupted races the
        conductor's repeat of it on a loaded machine: the repeat can start, and break again on
        the still-faulty device, before the test's own process gets to run.
        """
        self._say(f"{fault} {seconds}")

    def replug(self) -> None:
        """Plug it back in: a new pty behind the same path."""
        self._say("replug")

    def _say(self, command: str) -> None:
        assert self._proc is not None and self._proc.stdin is not None
        self._proc.stdin.write(command + "\n")
        self._proc.stdin.flush()
        answer = self._reply()
        if answer != "ok":
            raise RuntimeError(f"the {self.kind} emulator answered {answer!r} to {command!r}")

    def _reply(self) -> str:
        assert self._proc is not None and self._proc.stdout is not None
        line = self._proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the {self.kind} emulator process ended (rc {self._proc.poll()})")
        return line.strip()


def _device(kind: str, link_dir: Path) -> PtyDevice:
    if kind == "feetech":
        return FeetechBusEmulator({i: 2048 for i in IDS}, link_dir=link_dir)
    return MaestroEmulator(link_dir=link_dir)


def _fault_for(device: PtyDevice, fault: str, seconds: float) -> None:
    """Begin the fault now and end it after `seconds` on a timer of this process."""
    if fault == "silent":
        device.silent = True
        end = threading.Timer(seconds, lambda: setattr(device, "silent", False))
    else:
        device.unplug()
        end = threading.Timer(seconds, device.replug)
    end.daemon = True
    end.start()


def main(argv: list[str]) -> int:
    """Serve one device until `quit` or the end of stdin (the parent gone)."""
    kind, link_dir = argv
    with contextlib.suppress(OSError):  # without the right, the normal priority
        os.setpriority(os.PRIO_PROCESS, 0, -10)
    with _device(kind, Path(link_dir)) as device:
        print(f"port {device.port}", flush=True)
        for line in sys.stdin:
            command = line.split()
            if command == ["quit"]:
                break
            if command[:1] == ["silent"] and command[1:] in (["1"], ["0"]):
                device.silent = command[1] == "1"
            elif command == ["unplug"]:
                device.unplug()
            elif command[:1] in (["silent"], ["unplugged"]) and len(command) == 2:
                _fault_for(device, command[0], float(command[1]))
            elif command == ["replug"]:
                device.replug()
            else:
                print(f"unknown command {line.strip()!r}", flush=True)
                continue
            print("ok", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
