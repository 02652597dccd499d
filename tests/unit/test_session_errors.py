"""A session that cannot open says what is wrong, and what to do, in one line."""

import pytest

from services.core.session import make_config, open_session
from tests.processes import free_port


def test_a_port_in_use_says_something_listens_there_not_that_nothing_does():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    first = open_session(make_config(mode="router", listen=[endpoint]))
    try:
        with pytest.raises(ConnectionError) as exc:
            open_session(make_config(mode="router", listen=[endpoint]))
    finally:
        first.close()
    text = str(exc.value)
    assert "already listens there" in text and "is a router running" not in text
    assert "\n" not in text and ".rs:" not in text  # one line, no Rust source locations


def test_no_router_says_to_start_one():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    conf = make_config(mode="client", connect=[endpoint])
    conf.insert_json5("connect/timeout_ms", "200")
    with pytest.raises(ConnectionError, match="is a router running at the --connect endpoint"):
        open_session(conf)
