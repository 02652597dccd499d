"""The conductor's view of the rig's safety: what breaks a trial, when the session may go on."""

from services.experiment.rig_watch import RigWatch
from services.store.records import SafetyEvent

MS = 1_000_000


class Clock:
    def __init__(self) -> None:
        self.t = 0

    def __call__(self) -> int:
        return self.t


def watch() -> tuple[RigWatch, Clock]:
    clock = Clock()
    rig = RigWatch(monotonic=clock)
    rig.begin(1, 1)
    return rig, clock


def report(rig: RigWatch, clock: Clock, ms: int, arm: bool = False, eyes: bool = False) -> None:
    clock.t = ms * MS
    rig.device_state("actuation", arm, "e-stop: x" if arm else "", ms * MS)
    rig.device_state("eyes", eyes, "gaze stale" if eyes else "", ms * MS)


def test_a_new_safe_stop_breaks_the_trial_and_is_logged():
    rig, clock = watch()
    report(rig, clock, 0)
    assert rig.interruption(0) is None
    report(rig, clock, 20, eyes=True)
    assert rig.interruption(20 * MS) == "eyes: gaze stale"
    report(rig, clock, 40, arm=True, eyes=True)
    assert rig.interruption(40 * MS) == "eyes: gaze stale"  # the first cause is kept
    events = [(e.device, e.event) for e in rig.take_events()]
    assert events == [("eyes", "safe_stop"), ("actuation", "safe_stop")]
    assert rig.take_events() == []


def test_the_rig_is_safe_only_after_settling_with_fresh_states():
    rig, clock = watch()
    report(rig, clock, 0, arm=True)
    assert not rig.safe(0)
    for ms in range(20, 520, 20):
        report(rig, clock, ms)
    assert not rig.safe(500 * MS)  # clear since 20 ms: 480 ms < 500 ms settle
    report(rig, clock, 540)
    assert rig.safe(540 * MS)
    clock.t = 1200 * MS  # no state for 660 ms: not evidence of safety
    assert not rig.safe(1200 * MS)


def test_a_silent_device_breaks_a_trial_and_an_estop_holds_until_released():
    rig, clock = watch()
    report(rig, clock, 0)
    clock.t = 400 * MS
    assert rig.interruption(0) is None
    clock.t = 501 * MS
    assert "silent" in (rig.interruption(0) or "")
    rig.begin(2, 1)
    report(rig, clock, 600)
    rig.estop(True, "bump", "op@ctl", 600 * MS)
    assert rig.interruption(0) == "e-stop by op@ctl: bump"
    for ms in range(620, 1400, 20):
        report(rig, clock, ms)
    assert not rig.safe(1400 * MS)  # latched until released
    rig.estop(False, "", "op@ctl", 1400 * MS)
    for ms in range(1420, 2000, 20):
        report(rig, clock, ms)
    assert rig.safe(2000 * MS)


def _rig_event(i: int):
    from services.core import messages as m

    return m.RigEvent(seq=i, t_ns=i, host="h", service="decision", kind="restarting", text="x")


def test_a_flood_of_rig_events_is_rate_limited_capped_and_its_drops_counted_in_the_store_path():
    rig, clock = watch()
    kept, counted = [], 0
    sent = 0
    for attempt_start in (0, 40_000, 80_000):  # three attempts, each flooded, then a quiet one
        rig.begin(1 + attempt_start // 40_000, 1)
        for i in range(20_000):
            clock.t = (attempt_start + i // 10) * MS  # 10,000 events a second
            rig.rig_event(clock.t, _rig_event(sent))
            sent += 1
            if i % 7000 == 0:  # the conductor stores events at trial ends, interruptions
                events = rig.take_events()
                kept += [e for e in events if e.kind != "dropped"]
                counted += sum(e.code for e in events if e.kind == "dropped")
    events = rig.take_events()
    kept += [e for e in events if e.kind != "dropped"]
    dropped = [e for e in events if e.kind == "dropped"]
    counted += sum(e.code for e in dropped)
    limit = rig.rig_events
    assert len(kept) == limit.accepted and counted == limit.dropped == sent - len(kept)
    per_trial = {t: sum(1 for e in kept if e.trial == t) for t in (1, 2, 3)}
    # Each attempt: 2 s of flood → at most the burst + 2/s · 2 s, well under the per-attempt cap.
    assert all(n <= limit.burst + 2 * limit.per_s for n in per_trial.values()), per_trial
    assert dropped and dropped[-1].service == "experiment" and dropped[-1].trial == 3
    assert "rig events dropped (rate limit" in dropped[-1].text
    # A long session of floods stops at the session's cap, whatever the rate allows.
    for k in range(100):
        rig.begin(10 + k, 1)
        clock.t += 60_000 * MS  # a minute later: the bucket is full again
        for _ in range(300):
            rig.rig_event(clock.t, _rig_event(0))
    assert limit.accepted == limit.total
    assert any("cap of 1000 per session" in e.text for e in rig.take_events())


def test_a_forged_state_flipping_safe_stop_is_followed_but_its_records_are_bounded():
    rig, clock = watch()
    rig.begin(2, 1)
    flips = 100_000
    for i in range(flips):  # a forged actuation/state at 10 kHz, safe stop on and off
        clock.t = i * MS // 10
        rig.device_state("actuation", i % 2 == 0, "forged", clock.t)
    # The safety state follows every message: the trial is broken, the rig now safe (odd last).
    assert rig.interruption(clock.t) == "actuation: forged"
    events = rig.take_events()
    stored = [e for e in events if isinstance(e, SafetyEvent)]
    dropped = [e for e in events if not isinstance(e, SafetyEvent)]
    limit = rig.safety_events
    assert len(stored) == limit.accepted <= limit.burst + limit.per_s * 10 + 1  # 10 s of flood
    assert len(dropped) == 1 and dropped[0].kind == "dropped"
    assert dropped[0].code == limit.dropped == flips - len(stored)
    assert "safety events dropped" in dropped[0].text and dropped[0].trial == 2


def test_every_device_is_heard_only_once_each_has_sent_a_state():
    rig, clock = watch()
    assert not rig.heard_every_device()
    rig.device_state("actuation", True, "experiment not alive", 0)
    assert not rig.heard_every_device()  # the eyes not yet
    rig.device_state("eyes", False, "", 0)
    assert rig.heard_every_device()
    # The safe stop held while no conductor ran is on record, to be filed under the open trial.
    assert [(e.device, e.event, e.reason) for e in rig.take_events()] == [
        ("actuation", "safe_stop", "experiment not alive")
    ]


def test_another_conductor_holds_the_session_and_voids_a_trial_only_if_it_stays():
    rig, clock = watch()
    report(rig, clock, 0)
    report(rig, clock, 600)
    assert rig.safe(600 * MS)
    rig.rival("1800000000000000000-42-abc", True, 600 * MS)
    assert not rig.safe(600 * MS)
    assert "another conductor claims this rig" in rig.why_unsafe()
    report(rig, clock, 2_000)  # a newcomer gives way within its grace: the trial stands
    assert rig.interruption(2_000 * MS) is None
    rig.rival("1800000000000000000-42-abc", False, 2_000 * MS)
    report(rig, clock, 2_600)
    assert rig.safe(2_600 * MS)  # safe again once settled
    rig.rival("1800000000000000001-43-def", True, 2_600 * MS)
    report(rig, clock, 5_700)  # one that stays past the grace voids the running trial
    assert "another conductor on the rig" in (rig.interruption(5_700 * MS) or "")
    kinds = [(e.device, e.event) for e in rig.take_events() if e.device == "experiment"]
    assert kinds == [("experiment", "safe_stop"), ("experiment", "clear"),
                     ("experiment", "safe_stop")]


def test_the_earliest_claim_holds_the_rig():
    from hypothesis import given
    from hypothesis import strategies as st

    from services.core.claim import earliest, new_claim_id

    @given(st.lists(st.integers(1, 2**62), min_size=1, max_size=20, unique=True))
    def check(times):
        ids = [new_claim_id(t) for t in times]
        assert earliest(ids) == ids[times.index(min(times))]

    check()
