"""`nod lab secure --router-per-rig`: a router per rig, linked to a lab router, over mutual TLS.

Three routers on free loopback ports, each running the config the command wrote: the lab router,
rig1's and rig2's (rig2's started by `nod up --exec router` from its rig file), both rig routers
connected to the lab router. rig1's identities connect to rig1's router, rig2's to rig2's, the
lab's to the lab router. A refusal is observed, not assumed: each refused put is followed on the
same session by an allowed one that takes the same links as far as the refusal's first chance to
pass, then by one from the lab's side down the links into the rig it aimed at; every link
forwards in order, so once both markers have arrived, a refused put that had passed would have
too.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from services.core.session import make_config
from services.lab.secure import main as secure_main
from tests.processes import stop_all

from .conftest import ROOT, free_port, wait_for
from .lab_seen import Seen, put_until_seen

pytestmark = pytest.mark.integration
Opener = Callable[[str], zenoh.Session]


class Lab:
    """The three routers running, and sessions as any identity of the lab."""

    def __init__(self, out: Path, routers: list[subprocess.Popen]) -> None:
        self.out, self.routers = out, routers
        self.sessions: list[zenoh.Session] = []

    def open(self, config: zenoh.Config, what: str) -> zenoh.Session:
        deadline = time.monotonic() + 15
        while True:
            try:
                self.sessions.append(zenoh.open(config))
                return self.sessions[-1]
            except zenoh.ZError:
                dead = [p.args[-1] for p in self.routers if p.poll() is not None]
                if time.monotonic() > deadline or dead:
                    raise AssertionError(f"{what} could not connect (dead: {dead})") from None
                time.sleep(0.05)

    def session(self, folder: str) -> zenoh.Session:
        """A session as one identity (`rig1/arm`, `rig2/camera`, `lab/estop`…)."""
        config = make_config(mode="client", config_file=self.out / folder / "zenoh.json5")
        return self.open(config, f"the {folder} identity")

    def via(self, folder: str, rig: str) -> zenoh.Session:
        """A session as a lab identity (`lab/estop`), connected to rig's router instead."""
        text = (self.out / rig / "router" / "router.json5").read_text()
        endpoints = json.loads(text[text.index("{") :])["listen"]["endpoints"]
        config = make_config(
            mode="client", connect=endpoints, config_file=self.out / folder / "zenoh.json5"
        )
        return self.open(config, f"the {folder} identity at {rig}'s router")

    def as_router(self, rig: str) -> zenoh.Session:
        """A client session with rig's router certificate, straight to the lab router."""
        text = (self.out / rig / "router" / "router.json5").read_text()
        doc = json.loads(text[text.index("{") :])
        for key in ("listen", "access_control"):
            del doc[key]
        doc["mode"] = "client"
        return self.open(zenoh.Config.from_json5(json.dumps(doc)), f"{rig}'s router certificate")

    def close_sessions(self) -> None:
        for s in self.sessions:
            s.close()
        self.sessions.clear()


@pytest.fixture(scope="module")
def routers(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Lab]:
    """The identities and configs, the lab router and both rig routers running."""
    folder = tmp_path_factory.mktemp("lab")
    out = folder / "tls"
    lab_port, port1, port2 = free_port(), free_port(), free_port()
    # rig2's rig file names its router: `nod lab secure` reads it there, `nod up` starts it.
    rig2 = folder / "rig2.toml"
    rig2.write_text(
        f'[rig]\nname = "rig2"\nrouter = "tls/127.0.0.1:{port2}"\ntls = "tls/rig2"\n'
        '[hosts.control]\nrouter = true\nservices = ["monitor"]\n'
    )
    flags = f"--rigs rig1,rig2 --router-per-rig --router-host 127.0.0.1 --port {lab_port}"
    rig_routers = ["--rig-router", f"rig1=127.0.0.1:{port1}", "--rig-router", f"rig2={rig2}"]
    assert secure_main(["--out", str(out), *flags.split(), *rig_routers]) == 0

    def start(*args: str) -> subprocess.Popen:
        return subprocess.Popen(
            [sys.executable, "-m", "services.cli", *args],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )

    procs = [start("router", "--config", str(out / "router" / "router.json5"))]
    lab = Lab(out, procs)
    lab.session("lab/monitor")  # the lab router listens: the rig routers' first try connects
    procs += [
        start("router", "--config", str(out / "rig1" / "router" / "router.json5")),
        start("up", str(rig2), "--host", "control", "--exec", "router"),
    ]
    lab.session("rig1/monitor")
    lab.session("rig2/monitor")
    yield lab
    lab.close_sessions()
    stop_all(procs)


@pytest.fixture
def lab(routers: Lab) -> Iterator[Lab]:
    yield routers
    routers.close_sessions()


def refused(
    sender: zenoh.Session,
    keys: list[str],
    marker: tuple[Seen, str],
    down: tuple[zenoh.Session, Seen, str],
) -> list[str]:
    """Put each key once, then two markers; the keys any observer received (should be none).

    `marker`: an observer and a key `sender` may put that it receives over the links a refused
    put would take first; `down`: a lab session, an observer in the target rig, and a key the lab
    session may put there, down the last links.
    """
    n = time.monotonic_ns()
    for key in keys:
        sender.put(key, b"forged")
    seen, key = marker
    sender.put(key, b"marker %d" % n)
    wait_for(lambda: seen.has(key, b"marker %d" % n), 10, f"the marker {key}")
    lab, target, key = down
    put_until_seen(lab, target, key, b"down %d" % n)
    return [k for k in keys if seen.has(k, b"forged") or target.has(k, b"forged")]


def assert_refused(
    sender: zenoh.Session,
    keys: list[str],
    marker: tuple[Seen, str],
    down: tuple[zenoh.Session, Seen, str],
    who: str,
) -> None:
    """`refused` is empty: every key is refused; a line says how many, of whose (seen with -s)."""
    passed = refused(sender, keys, marker, down)
    print(f"\n{who}: {len(keys) - len(passed)} of {len(keys)} keys refused")
    assert not passed, passed


def test_the_lab_monitor_sees_both_rigs_services_through_their_routers(lab: Lab) -> None:
    from services.core.node import Node
    from services.core.session import Fabric
    from services.tools import lab_status

    lab_monitor = lab.session("lab/monitor")
    nodes = [
        Node(service, Fabric(rig=rig, config_file=lab.out / rig / role / "zenoh.json5"))
        for rig in ("rig1", "rig2")
        for service, role in (("decision", "arm"), ("vision", "camera"))
    ]
    try:
        for node in nodes:
            node.ready()
        stop = threading.Event()

        def services(session: zenoh.Session) -> dict[str, list[str]]:
            seen = lab_status.observe(session, 1.5, stop)
            return {
                r: sorted(s)
                for r, s in seen.alive.items()
                if s and r in {rig for rig, _ in seen.heartbeats}
            }

        want = {"rig1": ["decision", "vision"], "rig2": ["decision", "vision"]}
        wait_for(lambda: services(lab_monitor) == want, 15, "both rigs' services, heartbeats")
        # A rig's monitor, on its own router, hears its rig and nothing of the other.
        rig1 = Seen(lab.session("rig1/monitor"), "rig1")
        wait_for(lambda: rig1.has("nod/rig1/rig/status"), 5, "rig1's heartbeats at its monitor")
        wait_for(
            lambda: {"nod/rig1/alive/decision", "nod/rig1/alive/vision"} <= rig1.alive,
            5,
            "rig1's tokens at its monitor",
        )
        assert not [k for k in (*rig1.alive, *(k for k, _ in rig1.puts)) if "rig1" not in k]
    finally:
        for node in nodes:
            node.close()


def test_the_lab_estop_stops_both_rigs_and_a_rigs_estop_stays_in_its_rig(lab: Lab) -> None:
    arm1, arm2 = Seen(lab.session("rig1/arm"), "rig1"), Seen(lab.session("rig2/arm"), "rig2")
    lab_view, estop = Seen(lab.session("lab/monitor")), lab.session("lab/estop")
    for rig, arm in (("rig1", arm1), ("rig2", arm2)):  # engage and release, through the chain
        for what in ("estop", "release"):
            put_until_seen(estop, arm, f"nod/{rig}/safety/{what}", b"the lab's e-stop")
    control1 = lab.session("rig1/control")
    put_until_seen(control1, arm1, "nod/rig1/safety/estop", b"rig1's own")  # its own rig: yes
    into_rig2 = ["nod/rig2/safety/estop", "nod/rig2/safety/release"]
    passed = refused(
        control1,
        into_rig2,
        (lab_view, "nod/rig1/safety/release"),
        (estop, arm2, "nod/rig2/safety/release"),
    )
    assert passed == [], passed
    assert not [k for k, p in arm2.puts if p == b"rig1's own"], "rig1's e-stop reached rig2"
    # The lab e-stop drives nothing else of a rig, through the chain either.
    others = ["nod/rig1/actuation/cmd", "nod/rig2/experiment/trial", "nod/rig2/rig/event"]
    assert (
        refused(
            estop,
            others,
            (lab_view, "nod/rig2/safety/estop"),
            (estop, arm2, "nod/rig2/safety/release"),
        )
        == []
    )


def test_the_labs_identities_at_a_rig_router_reach_that_rig_only(lab: Lab) -> None:
    """With the lab router down, a rig is still stopped with the lab's e-stop at its router."""
    arm1, arm2 = Seen(lab.session("rig1/arm"), "rig1"), Seen(lab.session("rig2/arm"), "rig2")
    estop, screen = lab.via("lab/estop", "rig1"), lab.via("lab/monitor", "rig1")
    watch = Seen(screen)  # it asks for every rig; its rig router delivers rig1's only
    put_until_seen(estop, arm1, "nod/rig1/safety/estop", b"the lab's, at rig1's router")
    put_until_seen(lab.session("rig2/camera"), arm2, "nod/rig2/vision/hand", b"rig2's")
    put_until_seen(lab.session("rig1/camera"), watch, "nod/rig1/vision/hand", b"rig1's")
    assert not [k for k, _ in watch.puts if not k.startswith("nod/rig1/")], "rig2 leaked"
    into_rig2 = ["nod/rig2/safety/estop", "nod/rig2/safety/release"]
    assert (
        refused(
            estop,
            into_rig2,
            (arm1, "nod/rig1/safety/release"),
            (lab.session("lab/estop"), arm2, "nod/rig2/safety/release"),
        )
        == []
    )


def test_a_rig2_identity_cannot_reach_into_rig1_through_the_routers(lab: Lab) -> None:
    rig1 = Seen(lab.session("rig1/control"), "rig1")
    lab_view, estop = Seen(lab.session("lab/monitor")), lab.session("lab/estop")
    camera2 = lab.session("rig2/camera")
    put_until_seen(camera2, lab_view, "nod/rig2/vision/hand", b"own rig")
    forged = [
        "nod/rig1/vision/hand",
        "nod/rig1/vision/layout",
        "nod/rig1/eyes/cmd",
        "nod/rig1/safety/release",
        "nod/rig1/safety/estop",
        "nod/rig1/rig/status",
    ]
    token = camera2.liveliness().declare_token("nod/rig1/alive/vision")
    assert_refused(
        camera2,
        forged,
        (lab_view, "nod/rig2/vision/hand"),
        (estop, rig1, "nod/rig1/safety/release"),
        "rig2's camera into rig1 through rig2's and the lab router",
    )
    # Its rig's router enforces the rig's own ACL: a camera drives nothing of its rig either.
    rig2 = Seen(lab.session("rig2/arm"), "rig2")
    own = ["nod/rig2/decision/z_r", "nod/rig2/actuation/cmd", "nod/rig2/safety/release"]
    assert (
        refused(
            camera2, own, (rig2, "nod/rig2/vision/hand"), (estop, rig2, "nod/rig2/safety/estop")
        )
        == []
    )
    real = lab.session("rig1/arm").liveliness().declare_token("nod/rig1/alive/decision")
    wait_for(lambda: "nod/rig1/alive/decision" in rig1.alive, 10, "rig1's own token")
    assert "nod/rig1/alive/vision" not in rig1.alive | lab_view.alive, "rig2 forged a token"
    assert not [k for k, _ in rig1.puts if not k.startswith("nod/rig1/")], "rig1 heard rig2"
    token.undeclare()
    real.undeclare()


def test_a_rig_routers_identity_cannot_put_into_another_rig_at_the_lab_router(lab: Lab) -> None:
    """What a compromised or misconfigured rig1 router could send the lab router: rig1's only."""
    lab_view, estop = Seen(lab.session("lab/monitor")), lab.session("lab/estop")
    arm2 = Seen(lab.session("rig2/arm"), "rig2")
    rogue = lab.as_router("rig1")
    spy = lab.as_router("rig1")  # another session (a session hears its own puts)
    spy1, spy2 = Seen(spy, "rig1"), Seen(spy, "rig2")
    put_until_seen(rogue, lab_view, "nod/rig1/vision/hand", b"rig1's, from its router")
    forged = [
        "nod/rig2/safety/release",
        "nod/rig2/safety/estop",
        "nod/rig2/actuation/cmd",
        "nod/rig2/vision/hand",
        "nod/rig2/rig/event",
    ]
    token = rogue.liveliness().declare_token("nod/rig2/alive/actuation")
    assert_refused(
        rogue,
        forged,
        (lab_view, "nod/rig1/vision/hand"),
        (estop, arm2, "nod/rig2/safety/release"),
        "rig1's router identity into rig2 at the lab router",
    )
    # What the lab router forwards it: rig1's, and nothing of rig2's (rig1's comes after).
    put_until_seen(lab.session("rig2/camera"), lab_view, "nod/rig2/vision/hand", b"rig2's")
    put_until_seen(lab.session("rig1/camera"), spy1, "nod/rig1/vision/hand", b"rig1's camera")
    assert spy2.puts == [] and spy2.alive == set(), "the lab router forwarded rig2's"
    assert "nod/rig2/alive/actuation" not in lab_view.alive | arm2.alive, "a forged token"
    token.undeclare()


def test_nod_estop_as_the_lab_stops_both_rigs_arms_and_as_rig1_not_rig2s(
    lab: Lab,
    tmp_path: Path,
) -> None:
    """The real tools: each rig's actuation on its own router, `nod estop` through the chain."""
    from services.core import messages as m

    def arm(rig: str) -> subprocess.Popen:
        return subprocess.Popen(
            [
                sys.executable,
                "-m",
                "services.cli",
                "actuation",
                "--rig",
                rig,
                "--config",
                str(lab.out / rig / "arm" / "zenoh.json5"),
                "--state-dir",
                str(tmp_path / rig),
            ],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            stdin=subprocess.DEVNULL,
        )

    def estop(rig: str, identity: str, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [
                sys.executable,
                "-m",
                "services.cli",
                "estop",
                "--rig",
                rig,
                "--devices",
                "actuation",
                "--config",
                str(lab.out / identity / "zenoh.json5"),
                *args,
            ],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        )

    arms = [arm("rig1"), arm("rig2")]
    try:
        watch = lab.session("lab/monitor")
        states: dict[str, list[m.ArmStateMsg]] = {"rig1": [], "rig2": []}
        watch.declare_subscriber(
            "nod/*/actuation/state",
            lambda s: states[str(s.key_expr).split("/")[1]].append(
                m.decode(m.ArmStateMsg, s.payload.to_bytes())
            ),
        )
        wait_for(lambda: all(states.values()), 30, "both rigs' arm states at the lab monitor")
        other = estop("rig2", "rig1/control", "--timeout", "1")  # rig1's station, rig1's router
        assert other.returncode == 1 and "NOT by every device" in other.stdout, other.stdout
        seen = len(states["rig2"])
        wait_for(lambda: len(states["rig2"]) > seen, 10, "rig2's arm state after rig1's e-stop")
        assert not states["rig2"][-1].estop, "rig1's e-stop stopped rig2"
        for rig in ("rig1", "rig2"):
            engaged = estop(rig, "lab/estop", "--timeout", "10")
            assert engaged.returncode == 0 and "actuation: obeyed" in engaged.stdout, (
                engaged.stdout + engaged.stderr
            )
        wait_for(
            lambda: states["rig1"][-1].estop and states["rig2"][-1].estop,
            5,
            "both arms' latches engaged in their states",
        )
        released = estop("rig2", "lab/estop", "--release", "--timeout", "10")
        assert released.returncode == 0, released.stdout + released.stderr
        wait_for(lambda: not states["rig2"][-1].estop, 5, "rig2's arm released")
        assert states["rig1"][-1].estop, "releasing rig2 released rig1"
    finally:
        stop_all(arms)
