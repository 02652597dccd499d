"""What the participant's screen may show (services.display.screen), and the page's server."""

from __future__ import annotations

import json
import re
import socket
import threading
import urllib.error
import urllib.request
from http import HTTPStatus
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.core import messages as m
from services.display import web
from services.display.screen import WAIT, DisplayState, Screen, points
from services.display.web import (
    MAX_STREAMS,
    SECURITY_HEADERS,
    Admission,
    DisplayServer,
    Request,
    ScreenFeed,
    load_static,
    parse_request,
    response_head,
    route,
)
from tests.polling import wait_for

ROOT = Path(__file__).resolve().parents[2]
# Words that would tell a participant the condition or the robot's opinion.
REVEALING = re.compile(r"red|blue|consensus|dissensus|low|significant|none|\b(C|CH|D|DH)\b", re.I)


OPTION_NAMES = ("red", "blue", "green", "yellow")


def ev(phase: str, trial: int = 1, text: str = "", session: str = "S1", n: int = 2) -> Any:
    """A trial event over `n` options (one key space: two are the paper's red and blue)."""
    names = OPTION_NAMES[:n]
    return m.TrialEvent(seq=0, t_ns=0, options=names, phase=phase, trial=trial,  # type: ignore[arg-type]
                        mode="consensus", option=names[-1], text=text, session=session)


def res(trial: int, score: int, session: str = "S1", interrupted: bool = False,
        n: int = 2) -> Any:
    """A trial's result over `n` options."""
    names = OPTION_NAMES[:n]
    return m.TrialResult(seq=0, t_ns=0, options=names, trial=trial, mode="consensus",
                         option=names[1], robot=names[1], human=names[0], outcome="D",
                         score=score, session=session, interrupted=interrupted)


def live(session: str = "S1") -> DisplayState:
    """A display whose conductor is up and has begun `session`."""
    state = DisplayState()
    state.on_conductor(True)
    state.on_trial(ev("setup", 1, session=session))
    return state


@pytest.mark.parametrize("n", [2, 3])
def test_a_trial_shows_ready_the_countdown_go_then_wait_then_its_points(n):
    # the same screens whatever the number of options: nothing shown names one
    state = live()
    seen = []
    for msg in (ev("setup", text="significant", n=n), ev("countdown", text="1", n=n),
                ev("countdown", text="2", n=n), ev("countdown", text="3", n=n),
                ev("go", text="go", n=n), ev("end", text="human pressed", n=n)):
        state.on_trial(msg)
        seen.append((state.screen.kind, state.screen.big))
    state.on_result(res(1, 2, n=n))
    seen.append((state.screen.kind, state.screen.big, state.screen.small))
    assert seen == [("ready", "Get ready"), ("countdown", "1"), ("countdown", "2"),
                    ("countdown", "3"), ("go", "GO"), ("wait", "Please wait"),
                    ("score", "+2 points", "Total: +2 points")]


def test_the_conductor_gone_means_please_wait_even_mid_go_and_late_events_do_not_revive_go():
    state = live()
    state.on_trial(ev("go"))
    assert state.screen.kind == "go"
    assert state.on_conductor(False) and state.screen == WAIT
    assert not state.on_trial(ev("go"))  # a late event of the conductor gone
    assert not state.on_result(res(1, 2))
    assert state.screen == WAIT
    state.on_conductor(True)  # back: nothing is shown until its next event
    assert state.screen == WAIT
    state.on_trial(ev("setup", 2))
    assert state.screen.kind == "ready"


def test_thank_you_stays_when_the_conductor_exits_after_the_session():
    state = live()
    state.on_trial(ev("setup"))
    state.on_result(res(1, 2))
    state.on_trial(ev("session_end", text="complete"))
    assert state.screen == Screen("done", "Thank you", "Total: +2 points")
    state.on_conductor(False)
    assert state.screen.kind == "done"
    late = live()  # started just before the end: no result seen, no total (not "0 points")
    late.on_trial(ev("session_end", text="complete"))
    assert late.screen == Screen("done", "Thank you", "")


def test_no_total_unless_every_earlier_result_was_seen():
    state = DisplayState()
    state.on_conductor(True)
    state.on_trial(ev("setup", 3))  # joined at trial 3: trials 1-2 never seen
    state.on_result(res(3, 2))
    assert state.screen == Screen("score", "+2 points", "")
    state = live()
    for trial, score in ((1, 2), (2, -1)):
        state.on_trial(ev("setup", trial))
        state.on_result(res(trial, score))
    assert state.screen == Screen("score", "−1 point", "Total: +1 point")
    state.on_trial(ev("setup", 3))
    state.on_result(res(3, 0, interrupted=True))  # never scored: waits, counts as 0
    assert state.screen == WAIT
    state.on_trial(ev("setup", 4))
    state.on_result(res(4, 2))
    assert state.screen.small == "Total: +3 points"


def test_a_new_session_starts_a_new_total_and_a_stale_sessions_result_is_ignored():
    state = live("A")
    state.on_result(res(1, 2, session="A"))
    state.on_trial(ev("setup", 1, session="B"))
    assert not state.on_result(res(2, 2, session="A"))
    state.on_result(res(1, 0, session="B"))
    assert state.screen == Screen("score", "0 points", "Total: 0 points")
    state.on_trial(ev("go", 2, session="C"))  # joined mid-trial: waits for the next setup
    assert state.screen == WAIT


@pytest.mark.parametrize("bad", [ev("countdown", text=""), ev("countdown", text="x" * 13),
                                 ev("go", trial=0), ev("setup", trial=0)])
def test_events_it_cannot_show_honestly_are_refused(bad):
    state = live()
    state.on_trial(ev("go"))
    with pytest.raises(ValueError):
        state.on_trial(bad)
    assert state.screen.kind == "go"  # refused: nothing changed
    with pytest.raises(ValueError, match="trials count from 1"):
        state.on_result(res(0, 2))


@pytest.mark.parametrize("score,text", [(2, "+2 points"), (1, "+1 point"), (0, "0 points"),
                                        (-1, "−1 point"), (-3, "−3 points")])
def test_points_read_as_a_participant_reads_them(score, text):
    assert points(score) == text


PHASES = ("setup", "countdown", "go", "end", "interrupted", "abort", "session_end")
step = st.one_of(
    st.tuples(st.just("alive"), st.booleans()),
    # a countdown's text is its word; every other event's text may name the condition
    st.tuples(st.just("event"), st.sampled_from(PHASES), st.integers(1, 8),
              st.sampled_from(["1", "2", "3"]),
              st.sampled_from(["go", "low", "significant", "none", "red", "complete"]),
              st.sampled_from(["S1", "S2"])),
    st.tuples(st.just("result"), st.integers(1, 8), st.integers(-2, 2),
              st.sampled_from(["S1", "S2"]), st.booleans()),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(step, max_size=40))
def test_any_sequence_never_shows_go_without_a_conductor_nor_a_wrong_total_nor_the_condition(
    steps,
):
    state = DisplayState()
    alive, last_go, session_now = False, False, ""
    scores: dict[str, dict[int, int]] = {}
    for s in steps:
        if s[0] == "alive":
            alive = s[1]
            state.on_conductor(alive)
            last_go = last_go and alive
        elif s[0] == "event":
            _, phase, trial, word, label, session = s
            text = word if phase == "countdown" else label
            try:
                state.on_trial(ev(phase, trial, text, session))
            except ValueError:
                continue
            joined_mid_trial = session != session_now and phase != "setup"
            if session != session_now:  # a session (again) new here: counted from now on
                scores[session] = {}
            session_now = session
            last_go = alive and phase == "go" and not joined_mid_trial
        else:
            _, trial, score, session, interrupted = s
            state.on_result(res(trial, score, session, interrupted))
            if session == state.session:
                scores.setdefault(session, {})[trial] = 0 if interrupted else score
            last_go = last_go and session != state.session
        screen = state.screen
        assert (screen.kind == "go") == last_go, (s, screen)
        if not alive:
            assert screen.kind in ("wait", "done"), (s, screen)
        assert not REVEALING.search(f"{screen.big} {screen.small}"), screen
        seen = scores.get(state.session, {})
        if screen.small.startswith("Total"):
            assert seen and set(seen) == set(range(1, len(seen) + 1))
            assert screen.small == f"Total: {points(sum(seen.values()))}"


# --- the page's server --------------------------------------------------------------------


@pytest.fixture
def server():
    feed = ScreenFeed(WAIT.as_json(0))
    srv = DisplayServer(("127.0.0.1", 0), feed, load_static())
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    yield srv
    feed.close()
    srv.shutdown()
    srv.server_close()


def _get(srv: DisplayServer, path: str):
    return urllib.request.urlopen(f"http://127.0.0.1:{srv.port}{path}", timeout=5)


def test_the_page_and_its_files_are_served_with_a_self_only_policy(server):
    for path, kind in (("/", "text/html"), ("/display.js", "text/javascript"),
                       ("/display.css", "text/css")):
        with _get(server, path) as r:
            assert r.headers["Content-Type"].startswith(kind)
            assert r.headers["Content-Security-Policy"] == SECURITY_HEADERS[
                "Content-Security-Policy"]
            assert r.read()
    with pytest.raises(urllib.error.HTTPError) as err:
        _get(server, "/../pyproject.toml")
    assert err.value.code == 404


def test_the_shipped_page_fetches_nothing_from_outside():
    for name, body in load_static().items():
        text = body.decode()
        assert not re.search(r"(https?:)?//[a-z0-9.-]+\.[a-z]", text, re.I), name
        assert "@import" not in text and "url(" not in text, name


def _events(resp, n: int) -> list[dict]:
    out = []
    while len(out) < n:
        line = resp.readline().decode()
        assert line, "stream ended"
        if line.startswith("data: "):
            out.append(json.loads(line[6:]))
    return out


def test_the_stream_sends_the_screen_at_once_each_change_and_keepalives(server):
    with _get(server, "/events") as r:
        assert r.headers["Content-Type"] == "text/event-stream"
        assert r.readline() == b"retry: 1000\n"
        assert _events(r, 1)[0]["kind"] == "wait"
        server.feed.publish(Screen("go", "GO").as_json(1))
        assert _events(r, 1)[0] == {"kind": "go", "big": "GO", "small": "", "version": 1}
        assert _events(r, 1)[0]["kind"] == "go"  # the keep-alive repeats the current screen


def test_a_new_stream_beyond_the_limit_is_served_and_the_oldest_gives_way(server):
    opened = [_get(server, "/events") for _ in range(MAX_STREAMS)]
    try:
        for r in opened:
            _events(r, 1)
        with _get(server, "/events") as newest:  # the kiosk, reloaded: never refused
            assert _events(newest, 1)[0]["kind"] == "wait"
            assert opened[0].read().strip() == b""  # the oldest stream was ended for it
            for r in opened[1:]:
                assert _events(r, 1)[0]["kind"] == "wait"
    finally:
        for r in opened:
            r.close()


def _small_server(monkeypatch, max_pending: int, **constants: float):
    for name, value in constants.items():
        monkeypatch.setattr(web, name, value)
    feed = ScreenFeed(WAIT.as_json(0))
    srv = DisplayServer(("127.0.0.1", 0), feed, load_static(), Admission(max_pending, 2))
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    return srv


def _closed_by_server(sock: socket.socket) -> bool:
    """The server closed `sock` (EOF or reset); False while it is still open (5 s at most)."""
    sock.settimeout(5.0)
    try:
        while sock.recv(4096):
            pass  # a response (a 400) before the close
    except (ConnectionResetError, ConnectionAbortedError):
        return True
    except TimeoutError:
        return False
    return True


def test_unfinished_requests_are_closed_oldest_first_and_after_a_timeout(monkeypatch):
    srv = _small_server(monkeypatch, 4, HEADER_TIMEOUT_S=1.0)
    try:
        idle = [socket.create_connection(("127.0.0.1", srv.port)) for _ in range(4)]
        idle[1].sendall(b"GET /events HTTP/1.1\r\nHost: x\r\n")  # never finished
        wait_for(lambda: srv.admission.counts[0] == 4, 5, "four unfinished requests held")
        newer = socket.create_connection(("127.0.0.1", srv.port))
        assert _closed_by_server(idle[0])  # the oldest gave way to the fifth
        with _get(srv, "/events") as r:  # a real request is served all the while
            assert _events(r, 1)[0]["kind"] == "wait"
        assert all(_closed_by_server(s) for s in (*idle[1:], newer))  # the timeout
        wait_for(lambda: srv.admission.counts == (0, 0), 5, "no place held")
        for s in (*idle, newer):
            s.close()
    finally:
        srv.shutdown()
        srv.server_close()


def test_oversized_and_malformed_requests_get_400(server):
    for head in (b"GET /" + b"a" * web.MAX_HEADER_BYTES + b" HTTP/1.1\r\n\r\n",
                 b"hello there\r\n\r\n"):
        with socket.create_connection(("127.0.0.1", server.port), timeout=5) as s:
            s.sendall(head)
            assert s.recv(100).startswith(b"HTTP/1.1 400 ")


def test_a_stream_whose_client_stops_reading_is_dropped(monkeypatch):
    srv = _small_server(monkeypatch, 4, STALL_S=0.5)
    try:
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.connect(("127.0.0.1", srv.port))
        s.sendall(b"GET /events HTTP/1.1\r\nHost: x\r\n\r\n")
        wait_for(lambda: srv.admission.counts[1] == 1, 5, "the stream open")

        def dropped() -> bool:  # big screens fill the socket's buffers at once; it never reads
            srv.feed.publish({"kind": "wait", "big": "x" * 200_000, "small": "", "version": 1})
            return srv.admission.counts[1] == 0

        wait_for(dropped, 10, "the stalled stream dropped", every_s=0.2)
        assert srv.dropped == 0  # it timed out: nobody had to be closed for room
        s.close()
    finally:
        srv.shutdown()
        srv.server_close()


# --- pure parts: the request line, who gives way ------------------------------------------


@pytest.mark.parametrize(("line", "method", "path"), [
    (b"GET / HTTP/1.1\r\nHost: x\r\n\r\n", "GET", "/"),
    (b"GET /events?x=1 HTTP/1.0\r\n\r\n", "GET", "/events"),
    (b"head /display.js#a HTTP/1.1\n\n", "HEAD", "/display.js"),
])
def test_a_request_line_is_read(line, method, path):
    assert parse_request(line) == Request(method, path)


@pytest.mark.parametrize("line", [
    b"", b"GET /\r\n\r\n", b"GET / HTTP/2\r\n\r\n", b"GET x HTTP/1.1\r\n\r\n",
    b"G-T / HTTP/1.1\r\n\r\n", b"GET  / HTTP/1.1\r\n\r\n", "GET /\u00e9 HTTP/1.1".encode(),
])
def test_a_malformed_request_line_is_refused(line):
    with pytest.raises(ValueError):
        parse_request(line)


def test_routes_files_the_stream_and_refusals():
    files = load_static()
    assert route(Request("GET", "/events"), files) is None
    assert route(Request("GET", "/"), files)[:2] == (HTTPStatus.OK, "text/html; charset=utf-8")
    assert route(Request("GET", "/x"), files)[0] == HTTPStatus.NOT_FOUND
    assert route(Request("POST", "/"), files)[0] == HTTPStatus.METHOD_NOT_ALLOWED
    head = response_head(HTTPStatus.OK, "text/event-stream", None).decode()
    assert head.startswith("HTTP/1.1 200 OK\r\n") and head.endswith("\r\n\r\n")
    assert "Content-Length" not in head and "Connection: close" in head


def test_admission_the_oldest_unfinished_request_gives_way():
    a = Admission(max_pending=3, max_streams=2)
    assert [a.pending(c) for c in "abc"] == [[], [], []]
    assert a.pending("d") == ["a"]
    a.done("b")
    assert a.pending("e") == [] and a.counts == (3, 0)
    assert a.stream("c") == [] and a.counts == (2, 1)  # a stream is no longer pending


def test_admission_a_stalled_stream_gives_way_first_else_the_oldest():
    a = Admission(max_pending=8, max_streams=3)
    for c in "abc":
        a.stream(c)
    a.stalled("b", True)
    assert a.stream("d") == ["b"]
    assert a.stream("e") == ["a"]
    a.stalled("e", True)
    a.stalled("e", False)  # reads again
    assert a.stream("f") == ["c"] and a.counts == (0, 3)
    with pytest.raises(ValueError):
        Admission(max_pending=0)


@given(st.lists(st.tuples(st.sampled_from(["pending", "stream", "stalled", "done"]),
                          st.integers(0, 9)), max_size=60))
@settings(max_examples=200, deadline=None)
def test_admission_never_holds_more_than_its_bounds_and_always_admits(ops):
    a = Admission(max_pending=3, max_streams=2)
    for op, conn in ops:
        if op == "pending":
            assert conn not in a.pending(conn)
        elif op == "stream":
            assert conn not in a.stream(conn)
        elif op == "stalled":
            a.stalled(conn, True)
        else:
            a.done(conn)
        assert a.counts[0] <= 3 and a.counts[1] <= 2
