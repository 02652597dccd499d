"""The contract is declared once, and the user guide's reference and the code follow it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from services.core import contract
from services.core import messages as m
from services.core.contract import (
    TOPICS,
    ContractError,
    Topic,
    check_publisher,
    check_subscriber,
    markdown_table,
)

ROOT = Path(__file__).resolve().parents[2]
SERVICES = (
    "decision", "actuation", "eyes", "vision", "sim", "speaker", "display", "lsl", "experiment",
)


def test_reference_table_is_the_generated_one():
    """The user guide's contract table (docs/reference.md) is exactly the generated one."""
    page = (ROOT / "docs" / "reference.md").read_text(encoding="utf-8")
    assert page.count("<!-- contract:begin") == 1 and page.count("<!-- contract:end -->") == 1, (
        "docs/reference.md must hold the contract table between exactly one pair of markers"
    )
    begin = page.index("<!-- contract:begin")
    start = page.index("\n", begin) + 1
    end = page.index("<!-- contract:end -->")
    assert page[start:end] == markdown_table(), (
        "docs/reference.md's contract table is stale: run "
        "`python -m services.core.contract --update docs/reference.md`"
    )


def test_the_contract_table_lives_only_in_the_reference():
    """One table, one place: the README points to docs/reference.md instead of holding a copy."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "<!-- contract:begin" not in readme
    assert "docs/reference.md" in readme


@pytest.mark.parametrize("name", sorted(TOPICS))
def test_every_field_of_a_message_is_documented(name):
    t = TOPICS[name]
    for field in t.field_names():
        assert f"`{field}`" in t.fields, f"{name}: field {field!r} missing from the contract"


def _calls(kind: str) -> set[tuple[str, str]]:
    """(service, topic) of every `.publisher("…")` or `.subscribe("…")` in the services' code."""
    found = set()
    pattern = re.compile(rf'\.{kind}\(\s*"([a-z_]+/[a-z_]+)"')
    for service in SERVICES:
        for path in (ROOT / "services" / service).rglob("*.py"):
            for topic in pattern.findall(path.read_text()):
                found.add((service, topic))
    return found


def test_the_code_publishes_what_the_contract_says():
    declared = {(p, t.name) for t in TOPICS.values() for p in t.publishers if p in SERVICES}
    # Every long-running service sends its heartbeat through the shared Node runtime.
    node = (ROOT / "services/core/node.py").read_text()
    assert 'self.publisher("rig/status")' in node
    heartbeats = {(s, "rig/status") for s in SERVICES}
    # Answering queries is publishing: actuation and eyes answer for their e-stop latch
    # through the shared safety wiring.
    wiring = (ROOT / "services/safety/wiring.py").read_text()
    assert 'answer("safety/latch"' in wiring
    latches = {("actuation", "safety/latch"), ("eyes", "safety/latch")}
    code = _calls("publisher") | _calls("answer") | {("vision", "vision/hand")}
    assert code | heartbeats | latches == declared


def test_the_code_subscribes_to_what_the_contract_says():
    declared = {(s, t.name) for t in TOPICS.values() for s in t.subscribers if s in SERVICES}
    # vision reads rendered frames through its capture (ZenohCamera), not Node.subscribe;
    # actuation and eyes take the e-stop through the shared safety wiring.
    wiring = (ROOT / "services/safety/wiring.py").read_text()
    assert 'subscribe_urgent("safety/estop"' in wiring
    assert 'subscribe_urgent("safety/release"' in wiring  # on the safety path
    assert 'ask("safety/latch"' in wiring  # asking is subscribing: a starting device asks
    gated = {
        (service, topic)
        for service in SERVICES
        if "watch_safety_inputs(" in (ROOT / "services" / service / "service.py").read_text()
        for topic in ("safety/estop", "safety/release", "safety/latch")
    }
    assert {service for service, _ in gated} == {"actuation", "eyes"}
    code = _calls("subscribe") | _calls("ask") | {("vision", "sim/camera")}
    assert code | gated == declared


def test_undeclared_publishing_or_subscribing_is_refused():
    with pytest.raises(ContractError, match="declare it"):
        check_publisher("decision/z_r", "vision")
    with pytest.raises(ContractError, match="declare it"):
        check_subscriber("safety/estop", "sim")
    with pytest.raises(KeyError, match="unknown topic"):
        check_publisher("decision/z_q", "decision")
    assert check_publisher("safety/estop", "estop").qos.priority == "real_time"
    assert check_subscriber("decision/z_r", "actuation").message.KIND == "opinions"


def test_safety_and_protocol_messages_are_never_dropped():
    for name in ("safety/estop", "experiment/trial", "actuation/press", "eyes/cmd"):
        assert TOPICS[name].qos.congestion == "block", name
    assert TOPICS["safety/estop"].qos.priority == "real_time"


def test_every_topic_is_a_constant_named_after_its_key():
    constants = {k: v for k, v in vars(contract).items() if isinstance(v, Topic)}
    assert {k: v.name for k, v in constants.items()} == {
        name.upper().replace("/", "_"): name for name in TOPICS
    }
    assert all(TOPICS[t.name] is t for t in constants.values())
    assert contract.DECISION_Z_R.message is m.Opinions
    assert check_publisher(contract.EYES_CMD, "experiment") is contract.EYES_CMD
    assert check_subscriber(contract.DECISION_Z_R, "actuation") is TOPICS["decision/z_r"]
    with pytest.raises(ContractError, match="declare it"):
        check_publisher(contract.DECISION_Z_R, "vision")
    stray = Topic("decision/z_r", m.Opinions, ("vision",), (), "", contract.STREAM, "")
    with pytest.raises(KeyError, match="unknown topic"):  # only the declared constant counts
        check_publisher(stray, "vision")
