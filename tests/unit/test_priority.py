"""A device asks for a higher priority and never gives one up; without the right it says so."""

import os
import subprocess
import sys

from services.core.priority import raise_priority


def _run(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, timeout=60)


def test_a_device_process_runs_at_the_device_nice_or_says_why_not():
    out = _run(
        "import logging, os; logging.basicConfig(level=logging.INFO)\n"
        "from services.core.priority import raise_priority\n"
        "ok = raise_priority('actuation', -5); print(ok, os.getpriority(os.PRIO_PROCESS, 0))"
    )
    ok, nice = out.stdout.split()
    if ok == "True":
        assert int(nice) <= -5
    else:  # not permitted here: the process keeps its priority and one line says why
        assert int(nice) == os.getpriority(os.PRIO_PROCESS, 0)
        assert "normal priority" in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_a_priority_above_the_wanted_one_is_kept():
    now = os.getpriority(os.PRIO_PROCESS, 0)
    # Asking for a nice value no better than the current one changes nothing and succeeds.
    assert raise_priority("eyes", now + 5)
    assert os.getpriority(os.PRIO_PROCESS, 0) == now
