"""`nod status`'s clock offset: the least-delayed heartbeat of the window, not the last one."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from services.core import messages as m
from services.tools.status import Observation, report

OFFSET_NS = 3_000_000  # the service's clock runs 3 ms ahead of ours


@given(st.lists(st.integers(0, 80_000_000), min_size=1, max_size=6))
def test_the_offset_is_read_from_the_least_delayed_heartbeat(delays_ns):
    obs = Observation()
    for i, delay in enumerate(delays_ns):
        sent = 10**18 + i * 10**9  # our clock at sending, 1 Hz
        beat = m.NodeStatus(seq=i, t_ns=sent, service="decision", wall_ns=sent + OFFSET_NS,
                            started_ns=10**18)
        obs.heartbeat(beat, sent + delay)
    obs.alive.add("decision")
    row = report(obs, "r", ("decision",), now_wall=10**18 + 10**10)["services"][0]
    assert row["clock_offset_ms"] == round((OFFSET_NS - min(delays_ns)) / 1e6, 2)
    assert obs.heartbeats["decision"][1] == 10**18 + (len(delays_ns) - 1) * 10**9 + delays_ns[-1]


def test_a_piped_status_cuts_no_name_at_80_columns() -> None:
    """`nod status | grep …`: the full names, however long, and no trailing padding."""
    import io

    from services.tools import status

    name, key = "display-" + "x" * 90, "nod/rig1/" + "k" * 110
    doc = {
        "rig": "rig1", "down": [], "devices": {}, "events": [],
        "services": [{"service": name, "alive": True, "required": False}],
        "keys": [{"key": key, "count": 3, "rate_hz": 1.0, "age_s": 0.1}],
    }
    out = io.StringIO()  # not a terminal
    status._print(doc, False, out)
    text = out.getvalue()
    assert name in text and key in text and "…" not in text
    assert all(line == line.rstrip() for line in text.splitlines())
