"""The scale and soak benchmarks' pure helpers: seq gaps, hand → z_r pairs, the RSS verdict."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from benchmarks.rig_probe import Hot, rss_verdict, seq_gaps, service_name


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
