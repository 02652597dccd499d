"""The launcher's restart policy, on real child processes (no mocks): restart, backoff, give up."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from services.launch.supervisor import RestartPolicy, ServiceSpec, Supervisor, describe_exit

PY = sys.executable
FAST = RestartPolicy(backoff_initial_s=0.05, backoff_max_s=0.2, max_restarts=3, window_s=30.0)


def run_until(sup: Supervisor, done, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        sup.poll()
        if done():
            return
        time.sleep(0.01)
    raise AssertionError("timed out")


def test_backoff_doubles_and_is_capped() -> None:
    p = RestartPolicy(backoff_initial_s=0.25, backoff_max_s=5.0)
    assert [p.backoff(n) for n in range(7)] == [0.25, 0.5, 1.0, 2.0, 4.0, 5.0, 5.0]
    with pytest.raises(ValueError):
        RestartPolicy(backoff_initial_s=2.0, backoff_max_s=1.0)
    with pytest.raises(ValueError):
        RestartPolicy(max_restarts=-1)


def test_a_crashing_service_is_restarted_then_given_up(tmp_path: Path) -> None:
    events: list[tuple[str, str, int | None, int]] = []
    sup = Supervisor(FAST, on_event=lambda s, k, c, r, t: events.append((s, k, c, r)))
    counter = tmp_path / "runs"
    # Each run appends a line, then fails: the file counts the starts.
    code = f"open({str(counter)!r}, 'a').write('x\\n'); raise SystemExit(3)"
    sup.start(ServiceSpec("crashy", [PY, "-c", code], log=tmp_path / "crashy.log"))
    run_until(sup, lambda: sup.state("crashy") == "failed")
    assert len(counter.read_text().splitlines()) == 1 + FAST.max_restarts
    kinds = [k for _, k, _, _ in events]
    assert kinds.count("started") == 4 and kinds.count("restarting") == 3
    assert kinds[-1] == "gave_up" and events[-1][2] == 3 and events[-1][3] == 3
    assert sup.failed() == ["crashy"]


def test_a_configuration_error_is_not_restarted_and_its_cause_is_shown(tmp_path: Path) -> None:
    events: list[tuple[str, str, int | None, str]] = []
    sup = Supervisor(FAST, on_event=lambda s, k, c, r, t: events.append((s, k, c, t)))
    counter = tmp_path / "runs"
    code = (f"import sys; open({str(counter)!r}, 'a').write('x\\n'); "
            "print('nod actuation: cannot open /dev/ttyUSB9: no such port', file=sys.stderr); "
            "raise SystemExit(2)")
    sup.start(ServiceSpec("actuation", [PY, "-c", code], log=tmp_path / "actuation.log"))
    run_until(sup, lambda: sup.state("actuation") == "failed")
    assert len(counter.read_text().splitlines()) == 1  # started once: restarting cannot help
    (_, kind, exit_code, text), = [e for e in events if e[1] != "started"]
    assert kind == "gave_up" and exit_code == 2
    assert "configuration error" in text and "cannot open /dev/ttyUSB9" in text, text


def test_a_restart_says_the_last_line_the_service_wrote(tmp_path: Path) -> None:
    events: list[tuple[str, str]] = []
    sup = Supervisor(FAST, on_event=lambda s, k, c, r, t: events.append((k, t)))
    code = ("import sys; print('Traceback…\\nValueError: bad frame', file=sys.stderr); "
            "raise SystemExit(1)")
    sup.start(ServiceSpec("vision", [PY, "-c", code], log=tmp_path / "vision.log"))
    run_until(sup, lambda: any(k == "restarting" for k, _ in events))
    sup.stop()
    assert any(k == "restarting" and "ValueError: bad frame" in t for k, t in events), events


def test_a_clean_exit_is_final_and_a_signal_is_restarted(tmp_path: Path) -> None:
    sup = Supervisor(FAST)
    sup.start(ServiceSpec("once", [PY, "-c", "pass"]))
    run_until(sup, lambda: sup.state("once") == "done")
    time.sleep(0.2)
    sup.poll()
    assert sup.state("once") == "done" and sup.services["once"].restarts == 0

    marker = tmp_path / "second"
    # The restart sees NOD_RESTARTS=1 and its parent's pid (the launcher's lifeline).
    code = (
        "import os, time\n"
        f"open({str(marker)!r}, 'a').write(os.environ['NOD_RESTARTS'] + ' ' "
        "+ os.environ['NOD_PARENT_PID'] + '\\n')\n"
        "time.sleep(60)\n"
    )
    s = sup.start(ServiceSpec("victim", [PY, "-c", code]))
    run_until(sup, lambda: marker.exists())
    os.kill(s.proc.pid, signal.SIGKILL)
    t0 = time.monotonic()
    run_until(sup, lambda: len(marker.read_text().splitlines()) == 2)
    assert time.monotonic() - t0 < 2.0  # restarted well within the 2 s the rig needs
    assert marker.read_text().splitlines() == [f"0 {os.getpid()}", f"1 {os.getpid()}"]
    assert sup.services["victim"].last_code == -signal.SIGKILL
    sup.stop()
    assert sup.state("victim") == "stopped"


def test_restart_argv_is_used_for_restarts(tmp_path: Path) -> None:
    out = tmp_path / "argv"
    write = f"import sys; open({str(out)!r}, 'a').write(' '.join(sys.argv[1:]) + '\\n')"
    sup = Supervisor(FAST)
    sup.start(ServiceSpec(
        "conductor", [PY, "-c", write + "; raise SystemExit(1)", "--session", "abc"],
        restart_argv=lambda: [PY, "-c", write, "--resume", "abc"],
    ))
    run_until(sup, lambda: sup.state("conductor") == "done")
    assert out.read_text().splitlines() == ["--session abc", "--resume abc"]


def test_a_restart_with_nothing_left_to_do_ends_the_service_as_done(tmp_path: Path) -> None:
    events: list[tuple[str, str, str]] = []
    sup = Supervisor(FAST, on_event=lambda name, kind, code, restarts, text: events.append(
        (name, kind, text)))
    sup.start(ServiceSpec("conductor", [PY, "-c", "raise SystemExit(1)"],
                          restart_argv=lambda: None))
    run_until(sup, lambda: sup.state("conductor") == "done")
    assert sup.failed() == [] and sup.services["conductor"].restarts == 0
    assert ("conductor", "exited", "its work was done: not restarted") in events


def test_a_dead_conductor_restarts_by_what_the_store_holds_of_its_session(tmp_path: Path):
    from services.model.params import NodConfig
    from services.run import conductor_restart
    from services.store import Store

    db, fresh, resumed = tmp_path / "s.sqlite", ["--session", "s1"], ["--resume", "s1"]
    assert conductor_restart(db, "s1", fresh, resumed) == fresh  # no store yet
    with Store(db) as store:
        assert conductor_restart(db, "s1", fresh, resumed) == fresh  # died before its write
        store.begin_session("s1", "P01", "rig1", 1, 10**12, NodConfig().summary())
        assert conductor_restart(db, "s1", fresh, resumed) == resumed  # unfinished: resume
        store.finish_session("s1", 2 * 10**12, "aborted")
        assert conductor_restart(db, "s1", fresh, resumed) == resumed
        store.finish_session("s1", 3 * 10**12, "complete")
        assert conductor_restart(db, "s1", fresh, resumed) is None  # nothing left to do


def test_stop_terminates_then_kills(tmp_path: Path) -> None:
    sup = Supervisor(FAST)
    polite = sup.start(ServiceSpec("polite", [PY, "-c", "import time; time.sleep(60)"]))
    stubborn_code = (
        "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
        "print('ready', flush=True); time.sleep(60)"
    )
    log = tmp_path / "stubborn.log"
    stubborn = sup.start(ServiceSpec("stubborn", [PY, "-c", stubborn_code], log=log))
    deadline = time.monotonic() + 10
    while "ready" not in log.read_text() and time.monotonic() < deadline:
        time.sleep(0.02)
    t0 = time.monotonic()
    sup.stop(grace_s=0.5)
    assert time.monotonic() - t0 < 3.0
    assert polite.proc.returncode == -signal.SIGTERM
    assert stubborn.proc.returncode == -signal.SIGKILL
    # Once stopping, an exit is not restarted.
    sup.poll()
    assert {sup.state("polite"), sup.state("stubborn")} == {"stopped"}


def test_children_end_with_a_sigkilled_launcher(tmp_path: Path) -> None:
    """A launcher killed with SIGKILL runs no cleanup; its children still go (PR_SET_PDEATHSIG)."""
    pidfile = tmp_path / "child.pid"
    child = (
        "import os, time; from services.core.lifeline import die_with_parent; "
        f"assert die_with_parent(); open({str(pidfile)!r}, 'w').write(str(os.getpid())); "
        "time.sleep(60)"
    )
    launcher = (
        "import sys, time; from services.launch.supervisor import ServiceSpec, Supervisor; "
        "sup = Supervisor(); "
        f"sup.start(ServiceSpec('child', [sys.executable, '-c', {child!r}])); "
        "time.sleep(60)"
    )
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.Popen([PY, "-c", launcher], cwd=root)
    deadline = time.monotonic() + 15
    while not pidfile.exists() or not pidfile.read_text():
        assert time.monotonic() < deadline, "the child never started"
        time.sleep(0.02)
    pid = int(pidfile.read_text())
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 3
    while not _gone(pid):
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            raise AssertionError("the child outlived its SIGKILLed launcher")
        time.sleep(0.02)


def _gone(pid: int) -> bool:
    # The orphan is re-parented to init (or a subreaper): until reaped, a zombie still exists.
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z"
    except OSError:
        return True


def test_describe_exit() -> None:
    assert describe_exit(0) == "exited with code 0"
    assert describe_exit(3) == "exited with code 3"
    assert describe_exit(-9) == "killed by SIGKILL"
