"""The compute engine: a real local Dask cluster keeps input order, passes errors on, and an
unreachable scheduler is one clear line."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from services.compute.engine import (
    LOCAL_CONFIG,
    Engine,
    EngineError,
    _check_code,
    code_fingerprint,
    open_engine,
    scheduler_security,
)
from tests.processes import free_port


def slow_square(x: int) -> int:
    # The first items take longest, so they finish last: order must come from the engine.
    time.sleep(0.02 * (10 - x) if x < 10 else 0)
    return x * x


def fails_on_three(x: int) -> int:
    if x == 3:
        raise ValueError("three is not allowed")
    return x


@pytest.fixture(scope="module")
def engine() -> Iterator[Engine]:
    with open_engine(workers=2) as e:
        yield e


def test_map_keeps_the_input_order(engine: Engine) -> None:
    items = list(range(40))
    assert engine.map(slow_square, items, chunk=1) == [x * x for x in items]
    assert engine.map(slow_square, items) == [x * x for x in items]  # chunked by default
    assert engine.map(slow_square, []) == []
    assert engine.threads() == 2 and "local cluster of 2 workers" in engine.where


def test_imap_yields_in_order_and_an_early_stop_leaves_no_work(engine: Engine) -> None:
    it = engine.imap(slow_square, list(range(12)), chunk=1)
    assert [next(it) for _ in range(3)] == [0, 1, 4]
    it.close()  # the rest is cancelled, not left running on the cluster
    assert engine.map(slow_square, [5, 6]) == [25, 36]  # and the engine goes on


def test_a_task_error_reaches_the_caller(engine: Engine) -> None:
    with pytest.raises(ValueError, match="three is not allowed"):
        engine.map(fails_on_three, list(range(6)), chunk=2)


def test_an_unreachable_scheduler_is_one_clear_line() -> None:
    address = f"tcp://127.0.0.1:{free_port()}"  # nobody listens there
    t0 = time.monotonic()
    with pytest.raises(EngineError) as err, open_engine(address, timeout_s=1.0):
        pass
    message = str(err.value)
    assert "\n" not in message and address in message
    assert "dask scheduler" in message and "--scheduler" in message
    assert time.monotonic() - t0 < 30


def test_the_code_fingerprint_changes_with_any_source(tmp_path: Path) -> None:
    (tmp_path / "model").mkdir()
    (tmp_path / "model" / "a.py").write_text("x = 1\n")
    (tmp_path / "notes.txt").write_text("not code")
    first = code_fingerprint(tmp_path)
    assert len(first) == 12 and code_fingerprint(tmp_path) == first
    (tmp_path / "notes.txt").write_text("still not code")
    assert code_fingerprint(tmp_path) == first
    (tmp_path / "model" / "a.py").write_text("x = 2\n")
    assert code_fingerprint(tmp_path) != first
    (tmp_path / "model" / "a.py").write_text("x = 1\n")
    (tmp_path / "model" / "a.py").rename(tmp_path / "model" / "b.py")
    assert code_fingerprint(tmp_path) != first


class FakeClient:
    """What `Client.run(code_fingerprint)` answers: each worker's fingerprint (or its error)."""

    def __init__(self, answers: dict) -> None:
        self.answers = answers

    def run(self, fn, on_error: str) -> dict:
        return self.answers


def test_a_worker_with_other_code_is_refused_in_one_line() -> None:
    mine = code_fingerprint()
    _check_code(FakeClient({"tcp://a:1": mine, "tcp://b:2": mine}), "tcp://s:8786")  # accepted
    with pytest.raises(EngineError, match="tcp://b:2 of tcp://s:8786 runs other nod-hri code"):
        _check_code(FakeClient({"tcp://a:1": mine, "tcp://b:2": "0123456789ab"}), "tcp://s:8786")
    with pytest.raises(EngineError, match="cannot import services"):
        _check_code(FakeClient({"tcp://a:1": ModuleNotFoundError("services")}), "tcp://s:8786")


def worker_settings() -> dict[str, object]:
    import dask

    return {key: dask.config.get(key) for key in LOCAL_CONFIG}


def test_local_workers_run_without_the_profiler_and_frequent_chores(engine: Engine) -> None:
    """The embedded cluster's workers got its settings (they cost a 2-core cohort CPU time)."""
    seen = engine.client.run(worker_settings)
    assert len(seen) == 2
    assert all(s == LOCAL_CONFIG for s in seen.values())
    assert LOCAL_CONFIG["distributed.worker.profile.enabled"] is False


def test_the_local_cluster_listens_on_loopback_only(engine: Engine) -> None:
    """Nothing on the network reaches the embedded cluster: its scheduler and workers."""
    info = engine.client.scheduler_info()
    addresses = [engine.client.scheduler.address, *info["workers"]]
    assert len(addresses) == 3
    assert all(a.startswith("tcp://127.0.0.1:") for a in addresses), addresses


@pytest.mark.parametrize(
    ("address", "insecure", "says"),
    [
        ("tcp://192.168.10.5:8786", False, "refusing plain tcp to tcp://192.168.10.5:8786"),
        ("compute.lab:8786", False, "refusing plain tcp"),  # no scheme is tcp
        ("tls://192.168.10.5:8786", False, "needs this machine's client certificate"),
        ("ws://192.168.10.5:8786", True, "scheme ws:// is not supported"),
        ("tcp://compute.lab", True, "not a scheduler address"),
    ],
)
def test_a_scheduler_the_network_could_impersonate_is_refused_in_one_line(
    address: str, insecure: bool, says: str
) -> None:
    t0 = time.monotonic()
    with pytest.raises(EngineError, match=says) as err, open_engine(address, insecure=insecure):
        pass
    assert "\n" not in str(err.value) and time.monotonic() - t0 < 5  # refused before any network
    if "plain tcp" in says:
        assert "tls://HOST:PORT --tls-dir" in str(err.value) and "--insecure" in str(err.value)


def test_loopback_tcp_and_tls_with_a_client_identity_are_allowed(tmp_path: Path) -> None:
    from services.lab.compute import write_dask

    assert scheduler_security("tcp://127.0.0.1:8786", None) is None
    assert scheduler_security("tcp://[::1]:8786", None) is None
    assert scheduler_security("tcp://localhost:8786", None) is None
    assert scheduler_security("tcp://192.168.10.5:8786", None, insecure=True) is None
    write_dask(tmp_path, tmp_path, 30)
    sec = scheduler_security("tls://192.168.10.5:8786", tmp_path / "dask" / "client")
    assert sec is not None and sec.require_encryption
    assert sec.tls_client_cert == str(tmp_path / "dask" / "client" / "cert.pem")
    with pytest.raises(EngineError, match="lacks key.pem"):
        (tmp_path / "dask" / "client" / "key.pem").unlink()
        scheduler_security("tls://h:8786", tmp_path / "dask" / "client")
    (tmp_path / "dask" / "client" / "key.pem").write_bytes(
        (tmp_path / "dask" / "worker" / "key.pem").read_bytes()
    )  # a key that is not the certificate's
    with pytest.raises(EngineError, match="cannot use the certificates") as err:
        scheduler_security("tls://h:8786", tmp_path / "dask" / "client")
    assert "\n" not in str(err.value)


def slow_identity(x: int) -> int:
    time.sleep(0.2)
    return x


def test_a_cluster_that_dies_mid_map_is_one_engine_error() -> None:
    with open_engine(workers=1) as engine:
        it = engine.imap(slow_identity, list(range(40)), chunk=1)
        assert next(it) == 0
        engine.client.cluster.close()  # the scheduler and its worker go away mid-map
        with pytest.raises(EngineError, match=r"stopped computing after \d+ of 40 results") as err:
            list(it)
        assert "\n" not in str(err.value) and "restart its scheduler" in str(err.value)
