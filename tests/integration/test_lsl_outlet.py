"""`nod lsl` as its own process on a real Zenoh router, read by real LSL inlets (pylsl, liblsl) on
loopback: a simulated trial's markers arrive in order, each stamped with its event's rig time on
LSL's clock (not its arrival), and each pose's ẑ_h, z_r, b_r and hand centre arrive as one
sample stamped with the pose's time.

LSL finds outlets by multicast and broadcast; here it is told to stay on this machine (an
lsl_api.cfg through $LSLAPICFG: machine scope, IPv4 loopback as the only known peer, and a
session id of this test run's own, so no other LSL stream on the host is ever seen).
"""

from __future__ import annotations

import json
import math
import os
import time
import uuid

import pytest

from services.core import messages as m
from services.core.keys import Keys

from .conftest import wait_for

pylsl = pytest.importorskip("pylsl", reason="the lsl extra: pip install 'nod-hri[lsl]'")
pytestmark = pytest.mark.integration
KEYS = Keys("rig1")
STEP_NS = 100_000_000  # the events' stamps, 100 ms apart, all before they are sent
TOLERANCE_S = 0.0005  # stamp mapped by the service vs by this test, both on this host (~1 µs)
PAPER = ("red", "blue")


@pytest.fixture(scope="module", autouse=True)
def loopback_lsl(tmp_path_factory):
    """One LSL configuration for this process and the service (liblsl reads it once)."""
    cfg = tmp_path_factory.mktemp("lsl") / "lsl_api.cfg"
    cfg.write_text(
        "[ports]\nIPv6 = disable\n"
        "[multicast]\nResolveScope = machine\n"
        f"[lab]\nKnownPeers = {{127.0.0.1}}\nSessionID = nod-test-{uuid.uuid4().hex}\n"
        "[log]\nlevel = -2\n"
    )
    before = os.environ.get("LSLAPICFG")
    os.environ["LSLAPICFG"] = str(cfg)
    yield cfg
    if before is None:
        del os.environ["LSLAPICFG"]
    else:
        os.environ["LSLAPICFG"] = before


def _labels(info) -> list[str]:
    channel = info.desc().child("channels").child("channel")
    labels = []
    while not channel.empty():
        labels.append(channel.child_value("label"))
        channel = channel.next_sibling()
    return labels


def _inlet(source_id: str):
    found = pylsl.resolve_byprop("source_id", source_id, minimum=1, timeout=15)
    assert found, f"no LSL stream {source_id} on loopback"
    inlet = pylsl.StreamInlet(found[0], max_buflen=60)
    inlet.open_stream(timeout=15)
    return inlet


def _pull(inlet, n: int, timeout_s: float = 15) -> list[tuple[list, float]]:
    got: list[tuple[list, float]] = []
    deadline = time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < deadline:
        sample, stamp = inlet.pull_sample(timeout=0.2)
        if sample is not None:
            got.append((sample, stamp))
    return got


def _offset_s() -> float:
    """LSL's clock minus the wall clock, read here (the tightest of a few brackets)."""
    best = None
    for _ in range(5):
        a = pylsl.local_clock()
        wall = time.time_ns() / 1e9
        b = pylsl.local_clock()
        if best is None or b - a < best[0]:
            best = (b - a, (a + b) / 2 - wall)
    return best[1]


def test_the_inlet_gets_a_trials_markers_in_order_on_the_rigs_clock_and_one_sample_per_pose(
    router, client, spawn
):
    service = spawn("lsl")
    wait_for(lambda: any(r.ok is not None for r in client.liveliness().get(
        KEYS.alive("lsl"), timeout=0.3)) or service.poll() is not None, 30, "nod lsl up")
    assert service.poll() is None, service.log_path.read_text()[-2000:]
    markers, signals = _inlet("nod-rig1-markers"), _inlet("nod-rig1-signals")
    info = signals.info(timeout=5)
    assert info.nominal_srate() == pylsl.IRREGULAR_RATE and info.channel_count() == 5
    assert _labels(info) == ["z_h", "z_r", "b_r", "hand_x", "hand_y"]

    pub = {k: client.declare_publisher(KEYS.topic(k)) for k in (
        "experiment/trial", "experiment/result", "safety/estop", "actuation/state",
        "vision/hand", "decision/z_h", "decision/z_r", "decision/b_r")}
    base = time.time_ns() - 20 * STEP_NS  # stamps in the past: arrival can't be mistaken for them
    sent: list[tuple[str, int]] = []  # (event, t_ns)

    def put(key: str, msg: m.Message, event: str | None = None) -> None:
        pub[key].put(m.encode(msg))
        if event is not None:
            sent.append((event, msg.t_ns))

    def at(i: int) -> int:
        return base + i * STEP_NS

    common = {"trial": 4, "mode": "consensus", "option": "blue", "session": "S9",
              "options": PAPER}
    put("experiment/trial", m.TrialEvent(seq=1, t_ns=at(0), phase="setup", text="low",
                                          **common), "setup")
    for i, word in enumerate(("1", "2", "3"), start=1):
        put("experiment/trial", m.TrialEvent(seq=1 + i, t_ns=at(i), phase="countdown",
                                              text=word, **common), "countdown")
    put("experiment/trial", m.TrialEvent(seq=5, t_ns=at(4), phase="go", text="go", **common),
        "go")
    # Three poses: one whose b_r never comes (no row), one whose hand was not seen (NaN).
    for seq, i, seen in ((100, 5, True), (101, 5, True), (102, 6, False)):
        put("vision/hand", m.HandPose(seq=seq, t_ns=at(i), detected=True, center=(0.25, 0.75),
                                      landmarks=((0.25, 0.75),)) if seen else
            m.HandPose(seq=seq, t_ns=at(i)))
        put("decision/z_h", m.Observed(seq=seq, t_ns=at(i), src_seq=seq,
                                       **m.signed_fields(0.5)))
        put("decision/z_r", m.Opinions(seq=seq, t_ns=at(i), src_seq=seq,
                                       **m.signed_fields(-0.25 * seq / 100)))
        if seq != 101:
            put("decision/b_r", m.Opinions(seq=seq, t_ns=at(i), src_seq=seq,
                                           **m.signed_fields(1.5)))
    put("actuation/state", m.ArmStateMsg(seq=1, t_ns=at(7)))
    put("actuation/state", m.ArmStateMsg(seq=2, t_ns=at(8), safe_stop=True,
                                         safety_reason="stale decision"), "safe_stop")
    put("safety/estop", m.Estop(seq=1, t_ns=at(9), engaged=True, reason="test", id="e1"),
        "estop")
    put("actuation/state", m.ArmStateMsg(seq=3, t_ns=at(10)), "safe_stop_cleared")
    put("experiment/trial", m.TrialEvent(seq=6, t_ns=at(11), phase="end", text="human pressed",
                                          **common), "end")
    put("experiment/result", m.TrialResult(seq=1, t_ns=at(12), options=PAPER, trial=4,
                                           mode="consensus",
                                           option="blue", robot="blue", human="blue",
                                           outcome="C", score=2, session="S9"), "result")
    offset = _offset_s()

    got = _pull(markers, len(sent))
    texts = [json.loads(sample[0]) for sample, _ in got]
    assert [t["event"] for t in texts] == [e for e, _ in sent], texts
    assert [t["word"] for t in texts if t["event"] == "countdown"] == ["1", "2", "3"]
    assert texts[0] == {"event": "setup", "trial": 4, "session": "S9", "mode": "consensus",
                             "option": "blue", "gaze": "low"}
    assert texts[-1]["outcome"] == "C" and texts[-1]["score"] == 2
    errors = [stamp - (t_ns / 1e9 + offset) for (_, stamp), (_, t_ns) in zip(got, sent,
                                                                               strict=True)]
    assert all(abs(e) < TOLERANCE_S for e in errors), errors
    gaps = [b[1] - a[1] for a, b in zip(got, got[1:], strict=False)]
    want = [(b[1] - a[1]) / 1e9 for a, b in zip(sent, sent[1:], strict=False)]
    slips = [abs(g - w) for g, w in zip(gaps, want, strict=True)]
    assert max(slips) < 1e-4, (gaps, want)
    print(f"marker stamp − event time mapped here: max {max(map(abs, errors)) * 1e6:.1f} µs; "
          f"interval error max {max(slips) * 1e6:.2f} µs")

    rows = _pull(signals, 2)
    assert [values for values, _ in rows][0] == [0.5, -0.25, 1.5, 0.25, 0.75]
    last = rows[1][0]  # pose 102's (101 made none): no hand, no centre
    assert last[:3] == [0.5, -0.255, 1.5] and all(math.isnan(v) for v in last[3:]), last
    for (_, stamp), i in zip(rows, (5, 6), strict=True):
        assert abs(stamp - (at(i) / 1e9 + offset)) < TOLERANCE_S


def test_three_options_reopen_the_signals_with_a_channel_per_option(router, client, spawn):
    """One key space: a session over three options names them; the signals follow its set."""
    names = ("red", "blue", "green")
    service = spawn("lsl")
    wait_for(lambda: any(r.ok is not None for r in client.liveliness().get(
        KEYS.alive("lsl"), timeout=0.3)) or service.poll() is not None, 30, "nod lsl up")
    assert service.poll() is None, service.log_path.read_text()[-2000:]
    markers = _inlet("nod-rig1-markers")
    pub = {k: client.declare_publisher(KEYS.topic(k)) for k in (
        "experiment/trial", "vision/hand", "decision/z_h", "decision/z_r", "decision/b_r")}
    now = time.time_ns()
    pub["experiment/trial"].put(m.encode(m.TrialEvent(
        seq=1, t_ns=now, options=names, phase="setup", trial=1, option="green", text="low",
        session="S3")))
    assert json.loads(_pull(markers, 1)[0][0][0])["options"] == list(names)
    signals = _inlet("nod-rig1-signals-red-blue-green")
    info = signals.info(timeout=5)
    assert info.channel_count() == 11
    assert _labels(info)[:3] == ["z_h:red", "z_h:blue", "z_h:green"]
    vectors = {"z_h": (0.5, -0.25, -0.25), "z_r": (0.1, 0.0, -0.1), "b_r": (1.0, 1.0, -2.0)}
    for seq in (200, 201):  # the inlet may miss the first: it connects as the rows go out
        pub["vision/hand"].put(m.encode(m.HandPose(
            seq=seq, t_ns=now + seq, detected=True, center=(0.25, 0.75),
            landmarks=((0.25, 0.75),))))
        for q, values in vectors.items():
            cls = m.Observed if q == "z_h" else m.Opinions
            pub[f"decision/{q}"].put(m.encode(cls(seq=seq, t_ns=now + seq, src_seq=seq,
                                                  options=names, values=values)))
        time.sleep(0.2)
    rows = _pull(signals, 1)
    assert rows and rows[0][0] == [*vectors["z_h"], *vectors["z_r"], *vectors["b_r"], 0.25, 0.75]


def test_options_open_the_signals_with_the_rigs_option_set_before_any_message(router, client,
                                                                             spawn):
    """`nod lsl --options 3`: LabRecorder sees the three-option channels from the start."""
    service = spawn("lsl", "--options", "3")
    wait_for(lambda: any(r.ok is not None for r in client.liveliness().get(
        KEYS.alive("lsl"), timeout=0.3)) or service.poll() is not None, 30, "nod lsl up")
    assert service.poll() is None, service.log_path.read_text()[-2000:]
    info = _inlet("nod-rig1-signals-red-blue-green").info(timeout=5)
    assert info.channel_count() == 11
    assert _labels(info)[-5:] == ["b_r:red", "b_r:blue", "b_r:green", "hand_x", "hand_y"]
