"""The e-stop latch: only a release issued after every command obeyed lifts it, a restart never.
"""

from __future__ import annotations

import json
import random

from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.latch import MAX_SEEN, Latch, id_order, merge, new_command_id
from services.model.safety import SafetyParams, Watchdog
from services.safety.latch_file import LatchFile

orders = st.integers(1, 10_000)
ids = st.one_of(  # mostly ordered ids (`nod estop`'s), some without an order or malformed
    st.builds(lambda o, tag: f"{o}-{tag}", orders, st.text("abcdef0123456789", max_size=4)),
    st.text("abcdef0123456789-", max_size=6),
)
commands = st.lists(st.tuples(st.booleans(), ids), max_size=40)


def run(latch: Latch, cmds) -> Latch:
    for engaged, cid in cmds:
        latch, _ = latch.command(engaged, "why", "op@ctl", cid)
    return latch


def test_engage_then_release_with_a_fresh_id():
    latch, v = Latch().command(True, "bump", "op@ctl", "10-e1")
    assert v == "obeyed" and latch.engaged and latch.id == "10-e1" and latch.floor == 10
    assert latch.command(True, "bump", "op@ctl", "10-e1") == (latch, "repeat")
    assert latch.command(False, "", "op@ctl", "10-e1")[1] == "refused"  # the engage's own id
    assert latch.command(False, "", "op@ctl", "")[1] == "refused"  # no id
    assert latch.command(False, "", "op@ctl", "r1")[1] == "refused"  # an id without an order
    assert latch.command(False, "", "op@ctl", "9-r")[1] == "refused"  # issued before the engage
    released, v = latch.command(False, "", "op@ctl", "11-r1")
    assert v == "obeyed" and not released.engaged and released.id == "11-r1"


def test_a_replayed_release_cannot_lift_a_later_estop():
    latch = run(Latch(), [(True, "1-e1"), (False, "2-r1"), (True, "3-e2")])
    assert latch.command(False, "", "replay", "2-r1") == (latch, "refused")
    assert latch.engaged and latch.id == "3-e2"


def test_an_old_release_stays_refused_after_thousands_of_commands():
    # The audit's attack: after 80 commands the first release's id lifted a new e-stop (a list
    # of the 64 latest ids had forgotten it). Here 5,000 commands go by, then every release
    # ever obeyed is replayed against a fresh engage: each is refused.
    rng = random.Random(7)
    latch, releases, order = Latch(), [], 0
    for _ in range(5_000):
        order += rng.randint(1, 1_000)
        engage = rng.random() < 0.5
        latch, verdict = latch.command(engage, "x", "op", f"{order}-{rng.getrandbits(32):x}")
        if verdict == "obeyed" and not engage:
            releases.append(latch.id)
    latch, _ = latch.command(True, "new e-stop", "op", f"{order + 1}-new")
    assert len(releases) > 1_000 and len(latch.seen) <= MAX_SEEN
    for old in releases:
        assert latch.command(False, "", "replay", old) == (latch, "refused")


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.booleans(), ids), min_size=1, max_size=400), st.data())
def test_only_a_release_issued_after_every_obeyed_command_lifts_it(cmds, data):
    latch, obeyed = Latch(), []
    for engaged, cid in cmds:
        before = latch
        latch, verdict = latch.command(engaged, "why", "op", cid)
        if engaged:  # stopping is always obeyed
            assert latch.engaged
        elif before.engaged and not latch.engaged:  # a lift: ordered above every command obeyed
            assert verdict == "obeyed" and id_order(cid) is not None
            assert all(id_order(cid) > (id_order(o) or 0) for o in obeyed)
        elif before.engaged:
            assert verdict == "refused" and latch == before
        if verdict == "obeyed":
            obeyed.append(cid)
        assert len(latch.seen) <= MAX_SEEN
    # Whatever came before, no id already obeyed releases a later e-stop.
    engaged, _ = latch.command(True, "later", "op", new_command_id(latch.floor))
    replayed = data.draw(st.sampled_from(obeyed)) if obeyed else "1-x"
    assert engaged.command(False, "", "replay", replayed)[1] in ("refused", "repeat")
    assert engaged.command(False, "", "replay", replayed)[0].engaged


@given(commands, st.lists(commands, max_size=3))
def test_merge_is_engaged_if_any_holder_is(own_cmds, other_cmds):
    own = run(Latch(), own_cmds)
    others = [run(Latch(), c) for c in other_cmds]
    merged = merge(own, others)
    assert merged.engaged == (own.engaged or any(o.engaged for o in others))
    assert merged.floor == max(h.floor for h in (own, *others))
    # No id any holder obeyed can release the merged latch.
    for holder in (own, *others):
        for cid in holder.seen:
            if merged.engaged:
                assert merged.command(False, "", "x", cid)[1] in ("refused", "repeat")


def test_a_new_command_id_is_ordered_where_asked():
    assert id_order(new_command_id(1234)) == 1234
    assert id_order(new_command_id(0)) == 1  # never 0: a release must be above a fresh floor
    assert new_command_id(5) != new_command_id(5)  # a random tag
    assert id_order("12") is None and id_order("-3-x") is None and id_order("0-x") is None
    assert id_order("99999999999999999999-x") is None  # beyond 64 bits


def test_an_unknown_latch_holds_the_device_and_a_fault_stops_it():
    wd = Watchdog(SafetyParams(require_alive=("decision",)), ("z_r",))
    wd.set_alive("decision", True)
    wd.feed("z_r", 0)
    assert wd.check(0).reasons == ("e-stop state not known yet",)
    wd.adopt(Latch(True, "held by eyes", "op", "9-e", ("9-e",), 9))
    assert wd.estopped and wd.estop_id == "9-e" and wd.check(0).safe_stop
    assert wd.estop(False, "", "9-e") == "refused"
    assert wd.estop(False, "", "10-r") == "obeyed" and not wd.check(0).safe_stop
    wd.set_fault("bus silent (no status from servo 1)")
    assert wd.check(0).reasons == ("device fault: bus silent (no status from servo 1)",)
    wd.set_fault(None)
    assert not wd.check(0).safe_stop


def test_the_file_keeps_the_latch_and_a_torn_one_counts_as_engaged(tmp_path):
    f = LatchFile(tmp_path / "state", "rig1", "actuation")
    f.check_writable()
    assert f.load() == Latch()  # nothing saved yet: released
    latch = run(Latch(), [(True, "1-e1"), (False, "2-r1"), (True, "3-e2")])
    f.save(latch)
    assert f.load() == latch and f.load().floor == 3
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


def test_a_latch_saved_before_floors_keeps_its_commands_unreplayable(tmp_path):
    f = LatchFile(tmp_path, "rig1", "actuation")
    f.path.write_text(json.dumps({"engaged": True, "reason": "old", "source": "", "id": "7-e",
                                  "seen": ["5-r", "7-e"]}))
    latch = f.load()
    assert latch.engaged and latch.floor == 7
    assert latch.command(False, "", "replay", "5-r")[1] == "refused"


def test_a_full_disk_is_refused_at_start(small_disk):
    # An empty file can still be created on a full disk (a free inode): the probe writes bytes.
    f = LatchFile(small_disk.path / "state", "rig1", "actuation")
    small_disk.fill()
    try:
        f.check_writable()
    except OSError as exc:
        assert "No space left on device" in str(exc) and str(small_disk.path) in str(exc)
    else:
        raise AssertionError("a full latch folder was accepted")
    small_disk.free()
    f.check_writable()
