"""A trial's samples are bounded: a flood of hand poses is counted, not kept, and the press still
counts."""

import numpy as np

from services.core import messages as m
from services.experiment import trial_samples
from services.experiment.keyspace import Output
from services.experiment.trial_samples import TrialSamples
from services.model.judge import OptionsTrialJudge, TrialJudge
from services.model.params import NodConfig

START = ((0.5, 0.85),)
IN_RED = ((0.8, 0.2),)  # inside the default layout's red box


def pose(seq: int, where=START) -> m.HandPose:
    return m.HandPose(seq=seq, t_ns=1_000 + seq, detected=True, center=where[0], landmarks=where)


def test_a_flood_of_poses_stops_at_the_cap_counted_and_the_press_still_counts(monkeypatch):
    monkeypatch.setattr(trial_samples, "MAX_ROWS", 500)
    cfg = NodConfig()
    samples = TrialSamples(0, TrialJudge(cfg, cfg.layout))
    for seq in range(2_000):
        p = pose(seq)
        samples.on_hand(p)
        out = Output.of_signed(
            m.Observed(seq=seq, t_ns=p.t_ns, src_seq=seq, **m.signed_fields(0.2))
        )
        samples.on_output("z_h", out, p)
    samples.on_hand(pose(10))  # a kept pose's seq again: no new row, nothing dropped
    assert samples.dropped == 1_500  # every pose after the first 500
    assert len(samples.decimated(0)) == 500
    assert samples.human is None
    samples.on_hand(pose(3_000, IN_RED))  # not kept, but the judge sees the press
    assert samples.human == "red"
    assert samples.dropped == 1_501
    [record] = samples.drop_records(trial=2, attempt=1, t_ns=9)
    assert (record.trial, record.attempt, record.kind, record.code) == (2, 1, "dropped", 1_501)
    assert record.text == "1501 poses not recorded (at most 500 per trial)"


def test_nothing_dropped_nothing_recorded():
    cfg = NodConfig()
    samples = TrialSamples(0, TrialJudge(cfg, cfg.layout))
    samples.on_hand(pose(1))
    assert samples.dropped == 0 and samples.drop_records(1, 1, 0) == []


def test_at_three_options_the_hand_is_stored_and_the_vectors_leave_the_z_columns_null():
    """A vector has no faithful scalar: z columns NULL, the hand and the press as at two."""
    cfg = NodConfig()
    table = cfg.table(3)
    samples = TrialSamples(0, OptionsTrialJudge(cfg, table))
    for seq in range(3):
        p = pose(seq)
        samples.on_hand(p)
        samples.on_output("z_h", Output(p.t_ns, seq, np.array([0.3, -0.1, -0.2]), None), p)
    rows = samples.decimated(0)
    assert [(r.hand_x, r.hand_y) for r in rows] == [START[0]] * 3
    assert all(r.z_h is None and r.theta is None for r in rows)
    box = table.boxes[1]
    samples.on_hand(pose(5, (((box.x1 + box.x2) / 2, (box.y1 + box.y2) / 2),)))
    assert samples.human == 1  # the judge sees the press, a box index
