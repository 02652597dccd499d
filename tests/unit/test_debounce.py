"""The one debounce: the leading option of a stream, and its two-option reading, the sign."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.debounce import DebounceParams, LeaderDebouncer, SignDebouncer


def test_default_c_max_is_the_params_default():
    d = SignDebouncer()
    assert d.c_max == DebounceParams().c_max == 4
    assert not any(d.feed(x) for x in (1.0, -1.0, -1.0, -1.0))  # sets +, then 3 of 4 against
    assert d.feed(-1.0) and d.sign == -1 and d.onset == 1


samples = st.lists(st.sampled_from([-1.0, -0.3, 0.0, 0.2, 1.0]), min_size=1, max_size=60)


@settings(max_examples=200, deadline=None)
@given(samples, st.integers(1, 5))
def test_two_options_debounce_as_the_sign(xs: list[float], c_max: int) -> None:
    sign, leader = SignDebouncer(c_max), LeaderDebouncer(c_max)
    for x in xs:
        assert leader.feed(np.array([x, -x])) == sign.feed(x)
        assert leader.leader == {1: 0, -1: 1, 0: None}[sign.sign]
        assert leader.first == {1: 0, -1: 1, 0: None}[sign.first_sign]
        assert leader.samples == sign.samples
        if sign.sign:
            assert leader.onset == sign.onset


def test_a_third_option_restarts_the_run() -> None:
    deb = LeaderDebouncer(3)
    a, b, c = (np.eye(3)[j] * 2 - 2 / 3 for j in range(3))
    deb.feed(a)
    assert not deb.feed(b) and not deb.feed(b)
    assert not deb.feed(c)  # a run toward b interrupted by c: the count starts over for c
    assert not deb.feed(c) and deb.feed(c)
    assert deb.leader == 2 and deb.onset == 3
    assert not deb.feed(np.array([1.0, 1.0, -2.0]))  # a tie carries no option
    assert deb.leader == 2
