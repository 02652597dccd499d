"""The scale and soak benchmarks' helpers: seq gaps, pose → z_r pairs, RSS verdict, store check."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from benchmarks.rig_probe import Hot, rss_verdict, seq_gaps, service_name
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


def _trial(n: int, interrupted: bool = False) -> TrialRecord:
    return TrialRecord(n, "dissensus", None, "neutral", 0.0, 0.0, 10**9, 2 * 10**9, "red",
                       "blue", "D", 0, 0, 10, 0, "human pressed", interrupted=interrupted)


def test_soak_store_check_tells_lost_from_interrupted_trials(tmp_path):
    db = tmp_path / "soak.sqlite"
    store = Store(db)
    for k, person in enumerate(("P01", "P02", "P03")):
        store.begin_session(f"s{k}", person, "rig1", k, 10**9 * k, {})
        for n in range(1, 9):
            if person == "P02" and n == 5:
                continue  # lost: never stored
            broken = person == "P03" and n == 8
            if broken:
                store.write_interruption(f"s{k}", Interruption(8, 3, 10**9, 2 * 10**9,
                                                               "safe stop: stale vision/hand"))
            store.write_trial(f"s{k}", _trial(n, interrupted=broken), [])
        store.finish_session(f"s{k}", 10**10)
    store.close()
    problems = store_check(str(db), 3)
    assert problems[0] == "P02: session complete, 7/8 trials stored"
    assert problems[1].startswith("P03: 1 of 8 trials stored interrupted (1 breaks: safe stop")
    assert len(problems) == 2
    assert store_check(str(db), 4)[0] == "3 sessions of 3 participants stored, 4 expected"
