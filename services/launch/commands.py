"""The one builder of a service's command line, for every launcher.

`nod up` (a rig file's host, supervised; or one service through `nod up --exec` under systemd)
and `nod run --sim` (a whole simulated rig on this machine, an in-memory `Rig`) both start a
service with `command(rig, service)`: what a service is told — its session, its rig, its
parameters, its drivers and devices — is written once, here.
"""

from __future__ import annotations

from services.core.lifeline import nod_command
from services.core.rigfile import Rig, session_flags


def command(
    rig: Rig,
    service: str,
    *,
    sim_hardware: bool = False,
    connect: str | None = None,
    clock: tuple[float, int] | None = None,
    verbose: bool = False,
) -> list[str]:
    """The command line that starts `service` as the rig says.

    `sim_hardware` swaps every device for its simulation: sim arm and eyes drivers, and the sim
    participant in place of the camera (a whole rig on one machine, no hardware). `clock`
    (speed, epoch ns) puts the service on a shared simulated clock (`nod run --sim`).
    """
    host = rig.host_of(service)
    sec = rig.sections.get(service, {})
    name = "sim" if (sim_hardware and service == "vision") else service
    cmd = nod_command(name, *session_flags(rig, host, connect, service))
    if clock is not None:
        cmd += ["--speed", repr(clock[0]), "--epoch-ns", str(clock[1])]
    if verbose:
        cmd.append("-v")
    if rig.params is not None and name != "monitor":
        cmd += ["--params", str(rig.params)]
    if service in ("actuation", "eyes"):
        prefix = "arm" if service == "actuation" else "eyes"
        driver = "sim" if sim_hardware else sec.get("driver", "sim")
        cmd += ["--driver", driver]
        if driver != "sim":
            cmd += ["--port", sec["port"]]
        if "config" in sec:
            cmd += [f"--{prefix}-config", str(sec["config"])]
        if "trims" in sec and not sim_hardware:
            cmd += ["--trims", str(sec["trims"])]
        if "stale_ms" in sec:
            cmd += ["--stale-ms", repr(float(sec["stale_ms"]))]
        if "state_dir" in sec:
            cmd += ["--state-dir", str(sec["state_dir"])]
    elif name == "vision":
        cmd += ["--source", str(sec.get("source", "0")), "--tracker", sec.get("tracker", "aruco")]
        if "calibration" in sec:
            cmd += ["--calibration", str(sec["calibration"])]
    elif name == "speaker":
        driver = "sim" if sim_hardware else sec.get("driver", "sim")
        cmd += ["--driver", driver]
        if driver == "wav":
            cmd += ["--out", str(sec["out"])]
    elif name == "display" and "http" in sec:
        cmd += ["--http", sec["http"]]
    elif name == "sim" and "seed" in sec:
        cmd += ["--seed", str(int(sec["seed"]))]
    cmd += list(sec.get("args", []))
    return cmd
