"""`nod topic` and `nod ports` without a rig: keys, rates, rendering, USB ids, bad input.

The tools on a real router and a real 50 Hz stream: tests/integration/test_topic_tools.py.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from serial.tools.list_ports_common import ListPortInfo

from services.core import messages as m
from services.core.contract import TOPICS
from services.tools import observe, ports, topic, topic_list
from services.tools.observe import Rate, ToolError, interval_stats, resolve

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


# --- keys ---------------------------------------------------------------------------------------


def test_a_key_is_full_or_relative_to_the_rig():
    expected = observe.Target("nod/rig1/vision/hand", ("vision/hand",))
    assert resolve("vision/hand", "rig1") == expected
    assert resolve("/vision/hand/", "rig7").expr == "nod/rig7/vision/hand"
    full = resolve("nod/rig2/safety/estop", "rig1")  # a full key names its own rig
    assert full.expr == "nod/rig2/safety/estop" and not full.is_pattern


def test_wildcards_cover_the_contract_topics_they_match():
    target = resolve("safety/*", "rig1")
    assert target.is_pattern and target.topics == ("safety/estop", "safety/release")
    heard = tuple(t for t, spec in TOPICS.items() if not spec.queried_only)
    assert resolve("**", "rig1").topics == heard  # the queried-only latch carries no samples
    assert resolve("nod/*/vision/hand", "rig1").expr == "nod/*/vision/hand"


@pytest.mark.parametrize(
    ("key", "why"),
    [
        ("vision/hands", "unknown key"),
        ("nod/rig1", "names no topic"),
        ("nod/bad rig/vision/hand", "rig name"),
        ("vi*/hand", "not a key expression"),
        ("nope/*", "unknown key"),
        ("", "empty key"),
    ],
)
def test_a_bad_key_is_a_tool_error(key, why):
    with pytest.raises(ToolError, match=why):
        resolve(key, "rig1")


def test_decode_uses_the_contract_type_of_the_key():
    pose = m.HandPose(seq=4, t_ns=5, detected=False)
    assert observe.decode("nod/any/vision/hand", m.encode(pose)) == pose
    with pytest.raises(m.MessageError, match="hand: not valid msgpack"):
        observe.decode("nod/rig1/vision/hand", b"\xc1")
    with pytest.raises(m.MessageError, match="not a key of the contract"):
        observe.decode("nod/rig1/lab/extra", m.encode(pose))


def test_zenoh_errors_lose_their_rust_source_locations():
    text = (
        'Json5Err(Message { msg: "Endpoints must be of the form <protocol>/<address>: x at '
        '/root/.cargo/git/zenoh/endpoint.rs:615.", location: None }) at /root/x/config.rs:86.'
    )
    assert observe.clean(text) == "Endpoints must be of the form <protocol>/<address>: x"
    assert observe.clean("Unable to connect!  at /a/b/orchestrator.rs:447.") == "Unable to connect!"


# --- rates --------------------------------------------------------------------------------------


def test_rate_over_a_window_and_over_the_whole_run():
    rate = Rate(window=5)
    assert rate.total() is None and rate.window() is None
    rate.add(10.0)
    assert rate.total() is None  # a rate needs two arrivals
    for i in range(1, 11):  # 10 Hz, then 5 Hz
        rate.add(10.0 + (0.1 * i if i <= 6 else 0.6 + 0.2 * (i - 6)))
    window = rate.window()
    assert window.count == 5 and window.rate_hz == pytest.approx(5.0)
    assert window.min_s == pytest.approx(0.2) and window.std_s == pytest.approx(0, abs=1e-9)
    total = rate.total()
    assert total.count == 11 and total.rate_hz == pytest.approx(10 / 1.4)
    assert (total.min_s, total.max_s) == (pytest.approx(0.1), pytest.approx(0.2))
    times = [10.0 + t for t in (0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0, 1.2, 1.4)]
    assert total.std_s == pytest.approx(interval_stats(times).std_s)
    assert total.describe().startswith("7.1 Hz  min 100.0 ms  max 200.0 ms  std ")


def test_hz_lines():
    rate = Rate()
    assert topic.hz_line(rate, 0) == "no message yet"
    rate.add(1.0)
    assert topic.hz_line(rate, 0) == "1 message (a rate needs two)"
    rate.add(1.02)
    assert topic.hz_line(rate, 0).startswith("50.0 Hz  min 20.0 ms")
    assert topic.hz_line(rate, 2) == "no new messages"
    summary = topic.hz_summary("k", rate, 2.0, 1, 0)
    assert summary.startswith("summary: k: 2 messages in 2.0 s, 50.0") and "; 1 invalid" in summary
    assert topic.hz_summary("k", Rate(), 2.0, 0, 0) == "summary: k: 0 messages in 2.0 s"


# --- rendering ----------------------------------------------------------------------------------


def test_a_message_as_text_and_as_json():
    pose = m.HandPose(
        seq=7, t_ns=1_700_000_000_123_000_000, detected=True, center=(0.5, 0.25),
        landmarks=tuple((0.1 * i, 0.2) for i in range(6)),
    )
    line = topic.text_line("nod/rig1/vision/hand", pose)
    assert line.startswith("nod/rig1/vision/hand #7 ")
    assert line.endswith(' detected=true center=[0.5,0.25] landmarks=<6 points> source="camera"')
    row = json.loads(topic.json_line("nod/rig1/vision/hand", pose))
    assert row["key"] == "nod/rig1/vision/hand" and row["v"] == m.SCHEMA_VERSION == 3
    assert row["seq"] == 7
    assert row["center"] == [0.5, 0.25] and len(row["landmarks"]) == 6
    frame = m.VisionFrame(seq=1, t_ns=2, jpeg=b"\xff\xd8\xff" + b"\0" * 10)
    assert "jpeg=<13 bytes>" in topic.text_line("k", frame)
    assert "target=none" in topic.text_line("k", m.ArmStateMsg(seq=1, t_ns=2))


@pytest.mark.parametrize("n", [2, 3, 5])
def test_the_options_and_their_values_show_whatever_their_number(n):
    """One key space, schema 3: a layout or an opinion over N options shows each option's."""
    names = ("red", "blue", "green", "yellow", "white")[:n]
    layout = m.Layout(seq=1, t_ns=2, options=names,
                      boxes=tuple((0.1 * j, 0.1, 0.1 * j + 0.05, 0.2) for j in range(n)))
    line = topic.text_line("nod/rig1/vision/layout", layout)
    assert "options=[" + ",".join(f'"{o}"' for o in names) + "]" in line
    assert "points" not in line and line.count("[") == n + 2  # the set, the boxes, each box
    values = tuple([0.5] + [-0.5 / (n - 1)] * (n - 1))
    z_r = m.Opinions(seq=3, t_ns=4, options=names, values=values, src_seq=3)
    row = json.loads(topic.json_line("nod/rig1/decision/z_r", z_r))
    assert row["options"] == list(names) and row["values"] == pytest.approx(list(values))
    assert "values=[0.5," in topic.text_line("nod/rig1/decision/z_r", z_r)


def test_an_invalid_payload_is_one_line():
    text = topic.invalid_line("k", b"abc", "hand: bad\nthing", as_json=False)
    assert text == "k: INVALID payload (3 bytes): hand: bad thing"
    assert json.loads(topic.invalid_line("k", b"abc", "why", as_json=True)) == {
        "key": "k", "error": "why", "bytes": 3,
    }


def test_list_text_names_seen_silent_and_unknown_keys():
    seen = {"nod/r/vision/hand": topic_list.Seen(Rate()), "nod/r/lab/x": topic_list.Seen(Rate())}
    for t in (0.0, 0.5, 1.0):
        seen["nod/r/vision/hand"].rate.add(t)
    seen["nod/r/lab/x"].rate.add(0.0)
    seen["nod/r/lab/x"].invalid = 1
    report = topic_list.list_report("r", 2.0, seen, ["sim"])
    lines = topic_list.list_lines(report)
    text = "\n".join(lines)
    hand = next(line for line in lines if line.startswith("nod/r/vision/hand"))
    assert " 3 " in hand and "2.0 Hz" in hand and "HandPose" in hand and "vision, sim" in hand
    extra = next(line for line in lines if line.startswith("nod/r/lab/x"))
    assert "0.5 Hz (1 invalid)" in extra and "(not in the contract)" in extra
    silent = text.split("silent (in the contract", 1)[1]
    assert "nod/r/safety/estop" in silent and "nod/r/vision/hand" not in silent
    assert lines[-1] == "alive: sim"


# --- command line -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "text"),
    [
        (["echo", "no/such", "--connect", "tcp/127.0.0.1:1"], "unknown key 'no/such'"),
        (["hz", "vision/*"], "hz measures one key"),
        (["echo", "vision/hand", "--connect", "garbage"], "bad zenoh session flags: Endpoints"),
        (["list", "--connect", "tcp/127.0.0.1:1"], "cannot open the zenoh session"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(argv, text, capsys):
    assert topic.main(argv) == 2
    err = capsys.readouterr().err
    assert text in err and err.count("\n") == 1 and ".rs:" not in err


@pytest.mark.parametrize(
    "argv",
    [["hz", "vision/hand", "--window", "1"], ["echo", "k", "--count", "0"],
     ["list", "--duration", "nan"], ["list", "--rig", "a/b"], []],
)
def test_bad_flags_are_one_line_and_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        topic.main(argv)
    assert exc.value.code == 2
    assert capsys.readouterr().err.count("\n") == 1


# --- nod ports ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("vid", "pid", "says"),
    [
        (0x1A86, 0x7523, "--driver feetech"),
        (0x1A86, 0x55D3, "--driver feetech"),
        (0x1FFB, 0x0089, "Micro Maestro 6"),
        (0x1FFB, 0x008C, "--driver maestro"),
        (0x2341, 0x0043, "--driver arduino"),
        (0x0403, 0x6001, None),
        (None, None, None),
    ],
)
def test_known_usb_ids_name_the_driver(vid, pid, says):
    hint = ports.driver_hint(vid, pid, "/dev/ttyX")
    assert hint is None if says is None else says in hint


def test_a_maestro_port_says_whether_it_is_the_command_port():
    command = ports.driver_hint(0x1FFB, 0x008A, "/dev/ttyACM0", location="1-1.2:1.0")
    ttl = ports.driver_hint(0x1FFB, 0x008A, "/dev/ttyACM1",
                            interface="Pololu Mini Maestro 12-Channel USB Servo Controller TTL")
    assert "Command Port, the right one" in command and "NOT the one" in ttl


def test_a_port_as_json_and_text():
    info = ListPortInfo("/dev/ttyUSB0", skip_link_detection=True)
    info.vid, info.pid, info.serial_number, info.manufacturer = 0x1A86, 0x7523, "A1", "QinHeng"
    info.description = "USB Serial"
    row = ports.describe(info)
    assert row["device"] == "/dev/ttyUSB0" and row["usb"] == "1a86:7523"
    assert row["serial_number"] == "A1" and row["manufacturer"] == "QinHeng"
    assert "nod actuation --driver feetech --port /dev/ttyUSB0" in row["driver"]
    lines = ports.lines([row])
    assert lines[0] == "/dev/ttyUSB0  1a86:7523  USB Serial  serial A1  QinHeng"
    assert lines[1].startswith("    probably CH340") and "not listed" in lines[-1]
    assert ports.lines([])[0] == "no serial ports found"
    plain = ports.describe(ListPortInfo("/dev/ttyS0", skip_link_detection=True))
    assert plain["usb"] is None and plain["description"] is None and plain["driver"] is None


def test_nod_ports_json_is_a_list_and_exit_0():
    run = subprocess.run(
        [sys.executable, "-m", "services.cli", "ports", "--json"],
        cwd=ROOT, capture_output=True, text=True, timeout=30,
    )
    assert run.returncode == 0, run.stderr
    found = json.loads(run.stdout)
    assert isinstance(found, list)
    for p in found:
        assert {"device", "description", "usb", "serial_number", "manufacturer", "driver"} <= set(p)
