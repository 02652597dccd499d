"""The scale, soak and latency benchmarks' helpers: seq gaps, pose → z_r pairs, RSS verdict,
store check, priorities, the GC probe, tail attribution."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

from benchmarks.rig_probe import (
    Hot,
    overlapping,
    prioritize,
    rss_verdict,
    run_queue,
    seq_gaps,
    service_name,
    set_priority,
)
from benchmarks.soak import store_check
from services.store import Interruption, Store, TrialRecord


def test_seq_gaps_counts_missing_messages_and_not_restarts():
    assert seq_gaps([0, 1, 2, 3]) == (0, 4)
    assert seq_gaps([0, 1, 4, 5]) == (2, 6)  # 2 and 3 never came
    assert seq_gaps([5, 6, 6, 7]) == (0, 3)  # a repeat is no message
    assert seq_gaps([7, 8, 0, 1, 3]) == (1, 6)  # a restarted publisher counts from 0 again
    assert seq_gaps([]) == (0, 0)


@given(st.integers(0, 10_000), st.integers(1, 300), st.sets(st.integers(1, 298)))
def test_seq_gaps_finds_every_dropped_seq(start, n, dropped):
    dropped = {d for d in dropped if d < n - 1}  # the first and last arrive
    seqs = [start + i for i in range(n) if i not in dropped]
    assert seq_gaps(seqs) == (len(dropped), n)


def test_hot_pairs_a_pose_with_its_z_r_by_seq_and_stamp():
    hot = Hot()
    hot.pose(1, 100, arrived_ns=1_000_000)
    hot.pose(1, 200, arrived_ns=5_000_000)  # a restarted publisher's seq 1: another pose
    hot.pose(2, 300, arrived_ns=9_000_000)
    hot.z_r(1, 200, arrived_ns=7_000_000)
    hot.z_r(1, 100, arrived_ns=1_500_000)
    assert sorted(hot.latencies_ms()) == [0.5, 2.0]
    assert hot.unanswered(before_ns=10_000_000) == 1
    assert hot.unanswered(before_ns=9_000_000) == 0  # the last pose's answer may be on its way


def test_rss_verdict_is_the_spread_over_the_lowest():
    assert rss_verdict([100.0, 104.0, 109.0]) == (True, 0.09)
    flat, growth = rss_verdict([100.0, 105.0, 112.0])
    assert not flat and abs(growth - 0.12) < 1e-12
    assert rss_verdict([]) == (True, 0.0)


def test_service_name_reads_a_command_line():
    py = ["/venv/bin/python", "-P", "-m", "services.cli"]
    assert service_name([*py, "decision", "--rig", "rig2", "--speed", "1"]) == ("rig2", "decision")
    assert service_name([*py, "sim", "--seed", "3"]) == ("rig1", "sim")
    assert service_name([*py, "run", "--sim", "--join", "--rig", "rig3"]) == ("rig3", "launcher")
    assert service_name([*py, "run", "--sim", "--rigs", "4"]) == ("lab", "router")
    assert service_name(["/usr/bin/bash", "-c", "true"]) is None


def _trial(n: int, interrupted: bool = False, attempts: int = 1) -> TrialRecord:
    return TrialRecord(
        n,
        "dissensus",
        None,
        "neutral",
        0.0,
        0.0,
        10**9,
        2 * 10**9,
        "red",
        "blue",
        "D",
        0,
        0,
        10,
        0,
        "human pressed",
        interrupted=interrupted,
        attempts=attempts,
    )


def test_soak_store_check_tells_lost_from_interrupted_and_repeated_trials(tmp_path):
    db = tmp_path / "soak.sqlite"
    store = Store(db)
    for k, person in enumerate(("P01", "P02", "P03", "P04")):
        store.begin_session(f"s{k}", person, "rig1", k, 10**9 * k, {})
        for n in range(1, 9):
            if person == "P02" and n == 5:
                continue  # lost: never stored
            broken = person == "P03" and n == 8  # broken on all 3 attempts: stored interrupted
            repeated = person == "P04" and n == 2  # broken once, whole on attempt 2
            for attempt in range(1, 4 if broken else 2 if repeated else 1):
                store.write_interruption(
                    f"s{k}", Interruption(n, attempt, 10**9, 2 * 10**9, "eyes: gaze stale")
                )
            attempts = 3 if broken else 2 if repeated else 1
            store.write_trial(f"s{k}", _trial(n, interrupted=broken, attempts=attempts), [])
        store.finish_session(f"s{k}", 10**10)
    store.close()
    check = store_check(str(db), 4)
    assert check.problems == ["P02: session complete, 7/8 trials stored"]
    assert (check.trials, check.lost) == (31, 1)
    assert check.interrupted == [
        "P03 trial 8: stored interrupted after 3 attempts (eyes: gaze stale; eyes: gaze stale; "
        "eyes: gaze stale)"
    ]
    assert check.repeated == ["P04 trial 2: attempt 2 (eyes: gaze stale)"]
    missing = store_check(str(db), 5)
    assert missing.problems[0] == "4 sessions of 4 participants stored, 5 expected"
    assert missing.lost == 1 + 8  # a participant without a session lost all 8


def test_overlapping_counts_spans_that_meet_a_pause():
    spans = [(0, 10), (20, 30), (40, 50)]
    assert overlapping(spans, [(5, 2)]) == 1  # inside the first
    assert overlapping(spans, [(8, 15)]) == 2  # 8..23 meets the first two
    assert overlapping(spans, [(10, 10)]) == 0  # 10..20 touches both ends, overlaps neither
    assert overlapping(spans, []) == 0


def test_set_priority_refuses_an_unknown_kind():
    set_priority("none")  # leaves the caller as it is
    with pytest.raises(ValueError, match="one of none, nice, fifo"):
        set_priority("high")


@pytest.mark.skipif(os.geteuid() != 0, reason="raising a priority needs CAP_SYS_NICE")
def test_prioritize_sets_every_thread_of_a_running_process():
    child = subprocess.Popen(["sleep", "30"])
    try:
        assert prioritize(child.pid, "nice") >= 1
        assert os.getpriority(os.PRIO_PROCESS, child.pid) == -10
        prioritize(child.pid, "fifo")
        assert os.sched_getscheduler(child.pid) == os.SCHED_FIFO
        assert os.sched_getparam(child.pid).sched_priority == 10
    finally:
        child.kill()
        child.wait()
    assert prioritize(child.pid, "nice") == 0  # gone: nothing to set


def test_run_queue_sums_a_process_s_threads():
    wait, slices = run_queue(os.getpid())
    assert wait >= 0 and slices > 0
    assert run_queue(2**22 + 1) == (0, 0)  # no such process


def test_gc_probe_records_collections_and_freezes_on_sigusr1(tmp_path):
    log = tmp_path / "gc.json"
    script = f"""
import gc, os, signal
from benchmarks.rig_probe import gc_probe
pauses, _ = gc_probe("freeze", {str(log)!r})
for _ in range(3):
    a = []; a.append(a)  # a cycle for the collector
    gc.collect()
assert gc.get_freeze_count() == 0
os.kill(os.getpid(), signal.SIGUSR1)
assert gc.get_freeze_count() > 0 and gc.isenabled()
"""
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    subprocess.run([sys.executable, "-c", script], cwd=root, check=True, timeout=30)
    pauses = json.loads(log.read_text())
    assert len(pauses) >= 4  # three collections, and the freeze's own
    assert all(dur > 0 and gen == 2 for _, dur, gen in pauses)
    assert (tmp_path / "gc.json.settled").exists()  # what the benchmark waits for
