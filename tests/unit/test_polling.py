"""The tests' polling helpers: the value a check returns, the last look after the deadline."""

import time

import pytest

from tests.polling import eventually, wait_for


def test_eventually_returns_the_checks_value_or_none():
    calls = iter([0, [], "ready"])
    assert eventually(lambda: next(calls), 5.0, every_s=0.0) == "ready"
    looks: list[float] = []
    start = time.monotonic()
    assert eventually(lambda: looks.append(time.monotonic()), 0.05, every_s=0.02) is None
    assert looks[-1] >= start + 0.05  # the last look is after the deadline


def test_wait_for_fails_naming_what_it_waited_for():
    assert wait_for(lambda: {"a": 1}, 1.0, "a dict") == {"a": 1}
    with pytest.raises(AssertionError, match=r"timed out after 0.05 s waiting for the moon"):
        wait_for(lambda: False, 0.05, "the moon")
