import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.model.safety import SafetyParams, Watchdog

MS = 1_000_000


def make(stale_ms=250.0):
    wd = Watchdog(SafetyParams(stale_ms=stale_ms), ("z_r", "hand"))
    wd.set_alive("decision", True)
    wd.set_alive("vision", True)
    return wd


def test_fresh_inputs_allow_running():
    wd = make()
    wd.feed("z_r", 1000 * MS)
    wd.feed("hand", 1000 * MS)
    assert not wd.check(1200 * MS).safe_stop


def test_no_input_yet_is_unsafe():
    status = make().check(0)
    assert status.safe_stop and "no z_r yet" in status.reason


@given(st.integers(0, 10_000), st.integers(0, 10_000))
def test_stale_exactly_beyond_the_bound(age_z, age_h):
    wd = make()
    now = 100_000 * MS
    wd.feed("z_r", now - age_z * MS)
    wd.feed("hand", now - age_h * MS)
    assert wd.check(now).safe_stop == (max(age_z, age_h) > 250)


def test_lost_liveliness_stops_and_recovers():
    wd = make()
    wd.feed("z_r", 0)
    wd.feed("hand", 0)
    wd.set_alive("decision", False)
    assert "decision not alive" in wd.check(0).reason
    wd.set_alive("decision", True)
    assert not wd.check(0).safe_stop


def test_estop_latches_until_released():
    wd = make()
    wd.feed("z_r", 0)
    wd.feed("hand", 0)
    wd.estop(True, "operator")
    wd.feed("z_r", 1)
    assert wd.check(1).safe_stop and "operator" in wd.check(1).reason
    wd.estop(False)
    assert not wd.check(1).safe_stop


def test_old_timestamps_do_not_refresh():
    wd = make()
    wd.feed("z_r", 1000 * MS)
    wd.feed("z_r", 1 * MS)  # a late, reordered message
    wd.feed("hand", 1000 * MS)
    assert not wd.check(1100 * MS).safe_stop


def test_unknown_input_and_bad_bound():
    with pytest.raises(KeyError):
        make().feed("other", 0)
    with pytest.raises(ValueError):
        SafetyParams(stale_ms=0)


def test_a_required_service_never_seen_is_not_alive():
    # Liveliness is evidence of presence: a service that never declared its token (not started,
    # wrong rig, blocked by the network) must stop the device, not count as alive by default.
    wd = Watchdog(SafetyParams(stale_ms=250.0), ("z_r",))
    wd.feed("z_r", 0)
    status = wd.check(0)
    assert status.safe_stop
    assert "decision not alive" in status.reason and "vision not alive" in status.reason
    wd.set_alive("decision", True)
    assert wd.check(0).reasons == ("vision not alive",)
