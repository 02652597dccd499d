"""`nod lab secure --rigs rig1,rig2`: two rigs on one mutual-TLS router, isolated by identity.

Each test opens real TLS sessions with the identities the command wrote, against `nod router`
running the generated config on a free loopback port. A refusal is observed, not assumed: the
observer is the lab's monitor, which may read both rigs, and each refused put is followed on the
same session by an allowed one; the router forwards one face's messages in order, so once the
allowed one has arrived at the observer, a refused one that had passed would have too.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from services.core import messages as m
from services.core.session import make_config
from services.lab.secure import main as secure_main
from tests.processes import stop_all

from .conftest import ROOT, free_port, wait_for
from .lab_seen import Seen, put_until_seen

pytestmark = pytest.mark.integration
Opener = Callable[[str], zenoh.Session]


@pytest.fixture
def lab(tmp_path: Path) -> Iterator[Opener]:
    """Two rigs' identities and the lab's router running; yields a session opener by folder."""
    port = free_port()
    out = tmp_path / "lab"
    assert secure_main(["--out", str(out), "--rigs", "rig1,rig2", "--router-host", "127.0.0.1",
                        "--port", str(port)]) == 0
    router = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "router", "--config",
         str(out / "router" / "router.json5")],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    sessions: list[zenoh.Session] = []

    def session(folder: str) -> zenoh.Session:
        """A session as one identity of the lab (`rig1/arm`, `rig2/camera`, `lab/estop`…)."""
        config = make_config(mode="client", config_file=out / folder / "zenoh.json5")
        deadline = time.monotonic() + 10
        while True:
            try:
                sessions.append(zenoh.open(config))
                return sessions[-1]
            except zenoh.ZError:
                if time.monotonic() > deadline or router.poll() is not None:
                    raise AssertionError(f"the {folder} identity could not connect") from None
                time.sleep(0.05)

    yield session
    for s in sessions:
        s.close()
    stop_all([router])


def refused(sender: zenoh.Session, seen: Seen, keys: list[str], marker: str) -> list[str]:
    """Put each key once, then an allowed `marker` key; the keys that passed (should be none)."""
    for key in keys:
        sender.put(key, b"forged")
    sender.put(marker, b"after the forgeries")
    wait_for(lambda: seen.has(marker, b"after the forgeries"), 5, f"the marker {marker}")
    return [k for k in keys if seen.has(k, b"forged")]


def test_another_rigs_vision_cannot_drive_this_rig(lab: Opener) -> None:
    seen = Seen(lab("lab/monitor"))
    rig1 = Seen(lab("rig1/control"), "rig1")  # what rig1's own conductor hears
    vision2 = lab("rig2/camera")
    put_until_seen(vision2, seen, "nod/rig2/vision/hand", b"own rig")
    forged = ["nod/rig1/vision/hand", "nod/rig1/vision/layout", "nod/rig1/eyes/cmd",
              "nod/rig1/safety/release", "nod/rig1/safety/estop", "nod/rig1/rig/status"]
    passed = refused(vision2, seen, forged, "nod/rig2/vision/hand")
    print(f"\nrig2's vision identity into rig1: {len(forged) - len(passed)} of {len(forged)} "
          "keys refused (hand, layout, gaze, release, engage, heartbeat)")
    assert not passed, passed
    assert not [k for k, _ in rig1.puts if k.startswith("nod/rig2/")], "rig1 heard rig2"
    assert not [k for k, p in rig1.puts if p == b"forged"]


def test_a_rigs_estop_stops_only_its_rig_and_the_lab_estop_stops_every_rig(lab: Opener) -> None:
    seen = Seen(lab("lab/monitor"))
    control1, arm1 = lab("rig1/control"), lab("rig1/arm")
    put_until_seen(control1, seen, "nod/rig1/safety/estop", b"own rig")  # it stops its own rig
    into_rig2 = ["nod/rig2/safety/estop", "nod/rig2/safety/release"]
    assert refused(control1, seen, into_rig2, "nod/rig1/safety/release") == []
    assert refused(arm1, seen, ["nod/rig2/safety/estop"], "nod/rig1/safety/estop") == []
    estop = lab("lab/estop")
    for rig in ("rig1", "rig2"):
        for what in ("estop", "release"):  # engage, and release as `nod estop --release` does
            put_until_seen(estop, seen, f"nod/{rig}/safety/{what}", b"the lab's e-stop")
    # It stops and releases, and nothing else: it drives no rig and forges no device.
    others = ["nod/rig1/actuation/cmd", "nod/rig2/experiment/trial", "nod/rig2/eyes/cmd",
              "nod/rig1/actuation/state", "nod/rig2/rig/event"]
    assert refused(estop, seen, others, "nod/rig2/safety/estop") == []


def test_liveliness_tokens_cannot_be_forged_across_rigs(lab: Opener) -> None:
    lab_view = Seen(lab("lab/monitor"))
    rig1 = Seen(lab("rig1/control"), "rig1")
    arm2 = lab("rig2/arm")
    forged = arm2.liveliness().declare_token("nod/rig1/alive/actuation")
    own = arm2.liveliness().declare_token("nod/rig2/alive/actuation")  # its own rig's: passes
    wait_for(lambda: "nod/rig2/alive/actuation" in lab_view.alive, 5, "rig2's own token")
    real = lab("rig1/arm").liveliness().declare_token("nod/rig1/alive/decision")
    wait_for(lambda: "nod/rig1/alive/decision" in rig1.alive, 5, "rig1's own decision token")
    # Asked from a session without a liveliness subscriber: zenoh 1.10 may answer a session
    # that has one on the same keys with nothing at all (seen with no ACL too).
    monitor1 = lab("rig1/monitor")
    asked: list[str] = []

    def answered() -> bool:  # one query's answers can miss its window on a loaded host
        asked[:] = [str(r.ok.key_expr)
                    for r in monitor1.liveliness().get("nod/rig1/alive/*", timeout=2) if r.ok]
        return "nod/rig1/alive/decision" in asked

    wait_for(answered, 15, "rig1's decision token in a liveliness query")
    assert "nod/rig1/alive/actuation" not in asked, "rig2 forged rig1's actuation"
    assert "nod/rig1/alive/actuation" not in rig1.alive | lab_view.alive
    assert not [k for k in rig1.alive if k.startswith("nod/rig2/")], "rig1 saw rig2's tokens"
    for token in (forged, own, real):
        token.undeclare()


def test_a_rigs_hosts_see_nothing_of_another_rig_and_the_lab_monitor_sees_both(
    lab: Opener,
) -> None:
    lab_view, rig2 = Seen(lab("lab/monitor")), Seen(lab("rig2/monitor"), "rig2")
    # rig2 asks for rig1's keys, alone and among every rig's: the router admits neither.
    spies = [Seen(lab("rig2/monitor"), "rig1"), Seen(lab("rig2/control"), "*")]
    camera1, camera2 = lab("rig1/camera"), lab("rig2/camera")
    layout = camera1.declare_queryable("nod/rig1/vision/layout",
                                       lambda q: q.reply(q.key_expr, b"rig1's layout"))
    token = camera1.liveliness().declare_token("nod/rig1/alive/vision")
    put_until_seen(camera1, lab_view, "nod/rig1/vision/hand", b"rig1")
    put_until_seen(camera2, rig2, "nod/rig2/vision/hand", b"rig2")
    wait_for(lambda: "nod/rig1/alive/vision" in lab_view.alive, 5, "rig1's token at the lab")
    assert not [k for k, _ in rig2.puts if not k.startswith("nod/rig2/")], "rig2 heard rig1"
    assert not [k for spy in spies for k, _ in spy.puts if k.startswith("nod/rig1/")]
    assert not [k for spy in spies for k in spy.alive], "rig2 saw rig1's tokens"
    monitor2, lab_monitor = lab("rig2/monitor"), lab("lab/monitor")

    def answers(session: zenoh.Session) -> list[bytes]:
        return [r.ok.payload.to_bytes() for r in session.get("nod/rig1/vision/layout",
                                                             timeout=0.5) if r.ok]

    wait_for(lambda: answers(lab_monitor) == [b"rig1's layout"], 10, "the lab's layout query")
    assert answers(monitor2) == [], "rig2's monitor queried rig1's layout"
    alive = monitor2.liveliness().get("nod/*/alive/*", timeout=1)
    assert [str(r.ok.key_expr) for r in alive if r.ok] == [], "rig2 saw rig1 alive"
    layout.undeclare()
    token.undeclare()


def test_the_lab_view_lists_both_rigs_with_the_labs_identity_only(
    lab: Opener, tmp_path: Path,
) -> None:
    from services.core.node import Node
    from services.core.session import Fabric
    from services.tools import lab_status

    lab_monitor = lab("lab/monitor")  # once it connects, the router listens
    nodes = [Node("decision", Fabric(rig=rig, config_file=tmp_path / "lab" / rig / "arm" /
                                     "zenoh.json5")) for rig in ("rig1", "rig2")]
    try:
        for node in nodes:
            node.ready()
        stop = threading.Event()

        def rigs(session: zenoh.Session) -> list[str]:
            seen = lab_status.observe(session, 1.5, stop)
            return sorted({r for r, _ in seen.heartbeats} & set(seen.alive))

        wait_for(lambda: rigs(lab_monitor) == ["rig1", "rig2"], 15, "both rigs in the lab view")
        # A rig's own identity may not listen across rigs at all: the lab view needs the lab's.
        assert rigs(lab("rig1/monitor")) == []
    finally:
        for node in nodes:
            node.close()


def test_nod_estop_as_the_lab_stops_a_rigs_arm_and_as_another_rig_does_not(
    lab: Opener, tmp_path: Path,
) -> None:
    """The real tools: rig2's actuation under rig2's arm identity, `nod estop` under two others."""
    lab("lab/monitor")  # once it connects, the router listens
    folder = tmp_path / "lab"
    arm = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "actuation", "--rig", "rig2", "--config",
         str(folder / "rig2" / "arm" / "zenoh.json5"), "--state-dir", str(tmp_path / "state")],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL,
    )

    def estop(identity: str, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-m", "services.cli", "estop", "--rig", "rig2", "--devices",
             "actuation", "--config", str(folder / identity / "zenoh.json5"), *args],
            cwd=ROOT, capture_output=True, text=True, timeout=60,
        )

    try:
        watch = lab("rig2/monitor")
        wait_for(lambda: any(r.ok for r in watch.liveliness().get("nod/rig2/alive/actuation",
                                                                   timeout=0.5)),
                 30, "rig2's actuation")
        states: list[m.ArmStateMsg] = []
        watch.declare_subscriber("nod/rig2/actuation/state", lambda s: states.append(
            m.decode(m.ArmStateMsg, s.payload.to_bytes())))
        other = estop("rig1/control", "--timeout", "1")  # rig1's control station
        assert other.returncode == 1 and "NOT by every device" in other.stdout, other.stdout
        seen = len(states)
        wait_for(lambda: len(states) > seen, 10, "rig2's arm state after rig1's e-stop")
        assert not states[-1].estop, "rig1's e-stop stopped rig2"
        engaged = estop("lab/estop", "--timeout", "10")
        assert engaged.returncode == 0 and "actuation: obeyed" in engaged.stdout, (
            engaged.stdout + engaged.stderr)
        wait_for(lambda: states[-1].estop, 5, "the arm's latch engaged in its state")
        released = estop("lab/estop", "--release", "--timeout", "10")
        assert released.returncode == 0, released.stdout + released.stderr
    finally:
        stop_all([arm])
