from services.model.debounce import DebounceParams, SignDebouncer


def test_default_c_max_is_the_params_default():
    d = SignDebouncer()
    assert d.c_max == DebounceParams().c_max == 4
    assert not any(d.feed(x) for x in (1.0, -1.0, -1.0, -1.0))  # sets +, then 3 of 4 against
    assert d.feed(-1.0) and d.sign == -1 and d.onset == 1
