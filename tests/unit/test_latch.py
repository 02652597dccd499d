"""The e-stop latch: only a release with a fresh id lifts it, a restart never does."""

from __future__ import annotations

import json

from hypothesis import given
from hypothesis import strategies as st

from services.model.latch import MAX_SEEN, Latch, merge
from services.model.safety import SafetyParams, Watchdog
from services.safety.latch_file import LatchFile

ids = st.text("abcdef0123456789", min_size=0, max_size=6)
commands = st.lists(st.tuples(st.booleans(), ids), max_size=40)


def run(latch: Latch, cmds) -> Latch:
    for engaged, cid in cmds:
        latch, _ = latch.command(engaged, "why", "op@ctl", cid)
    return latch


def test_engage_then_release_with_a_fresh_id():
    latch, v = Latch().command(True, "bump", "op@ctl", "e1")
    assert v == "obeyed" and latch.engaged and latch.id == "e1"
    assert latch.command(True, "bump", "op@ctl", "e1") == (latch, "repeat")
    assert latch.command(False, "", "op@ctl", "e1")[1] == "refused"  # the engage's own id
    assert latch.command(False, "", "op@ctl", "")[1] == "refused"  # no id
    released, v = latch.command(False, "", "op@ctl", "r1")
    assert v == "obeyed" and not released.engaged and released.id == "r1"


def test_a_replayed_release_cannot_lift_a_later_estop():
    latch = run(Latch(), [(True, "e1"), (False, "r1"), (True, "e2")])
    assert latch.command(False, "", "replay", "r1") == (latch, "refused")
    assert latch.engaged and latch.id == "e2"


@given(commands)
def test_only_a_fresh_release_ever_lifts_it(cmds):
    latch = Latch()
    for engaged, cid in cmds:
        before = latch
        latch, verdict = latch.command(engaged, "why", "op", cid)
        if engaged:  # stopping is always obeyed
            assert latch.engaged
        elif before.engaged and not latch.engaged:  # a lift: a fresh, non-empty id
            assert verdict == "obeyed" and cid and cid not in before.seen
        elif before.engaged:
            assert verdict == "refused" and latch == before
        assert len(latch.seen) <= MAX_SEEN


@given(commands, st.lists(commands, max_size=3))
def test_merge_is_engaged_if_any_holder_is(own_cmds, other_cmds):
    own = run(Latch(), own_cmds)
    others = [run(Latch(), c) for c in other_cmds]
    merged = merge(own, others)
    assert merged.engaged == (own.engaged or any(o.engaged for o in others))
    # No id any holder used can release the merged latch.
    for holder in (own, *others):
        for cid in holder.seen[-5:]:
            if merged.engaged:
                assert merged.command(False, "", "x", cid)[1] == "refused"


def test_an_unknown_latch_holds_the_device_and_a_fault_stops_it():
    wd = Watchdog(SafetyParams(require_alive=("decision",)), ("z_r",))
    wd.set_alive("decision", True)
    wd.feed("z_r", 0)
    assert wd.check(0).reasons == ("e-stop state not known yet",)
    wd.adopt(Latch(True, "held by eyes", "op", "e9", ("e9",)))
    assert wd.estopped and wd.estop_id == "e9" and wd.check(0).safe_stop
    assert wd.estop(False, "", "e9") == "refused"
    assert wd.estop(False, "", "r9") == "obeyed" and not wd.check(0).safe_stop
    wd.set_fault("bus silent (no status from servo 1)")
    assert wd.check(0).reasons == ("device fault: bus silent (no status from servo 1)",)
    wd.set_fault(None)
    assert not wd.check(0).safe_stop


def test_the_file_keeps_the_latch_and_a_torn_one_counts_as_engaged(tmp_path):
    f = LatchFile(tmp_path / "state", "rig1", "actuation")
    f.check_writable()
    assert f.load() == Latch()  # nothing saved yet: released
    latch = run(Latch(), [(True, "e1"), (False, "r1"), (True, "e2")])
    f.save(latch)
    assert f.load() == latch
    assert sorted(p.name for p in f.path.parent.iterdir()) == [f.path.name]  # no temp left
    f.path.write_text('{"engaged": fal')
    torn = f.load()
    assert torn.engaged and "corrupt" in torn.reason
    f.path.write_text(json.dumps({"engaged": "no", "reason": "", "source": "", "id": "",
                                  "seen": []}))
    assert f.load().engaged


def test_a_latch_folder_that_cannot_be_written_is_refused(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    f = LatchFile(blocker / "state", "rig1", "eyes")
    try:
        f.check_writable()
    except OSError as exc:
        assert "cannot keep the e-stop latch" in str(exc)
    else:
        raise AssertionError("a latch folder under a file was accepted")
