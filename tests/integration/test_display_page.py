"""The participant's page in a real headless browser: `nod display` as its own process on a real
Zenoh router, a client publishing the conductor's events, Debian's chromium reading the page
through chromedriver (selenium): countdown digits, go, the points and the total; then the
conductor's liveliness gone, and then the display service itself gone, each → "Please wait"."""

from __future__ import annotations

import os
import re
import shutil
import time

import pytest

from services.core import messages as m
from services.core.keys import Keys

from .conftest import Collector, wait_for

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")
CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
# Flags that keep a headless chromium off the network: this machine refuses any connection that
# is not to loopback, and a browser's background services would try.
CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--window-size=1280,800",
)


def _browser_or_skip():
    """A WebDriver on Debian's chromium; skipped where it is not installed (never under CI)."""
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    missing = [p for p in (CHROMIUM, CHROMEDRIVER) if not shutil.which(p)]
    if missing:
        why = f"{' and '.join(missing)} missing: apt-get install chromium chromium-driver"
        if os.environ.get("CI"):  # .ci/run installs them: missing there is a failure
            pytest.fail(why)
        pytest.skip(why)
    return webdriver, Service


@pytest.fixture
def browser(tmp_path):
    webdriver, Service = _browser_or_skip()
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in (*CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'chromium-profile'}"):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    yield driver
    driver.quit()


class Conductor:
    """What the display listens to: the conductor's liveliness and its two event keys."""

    def __init__(self, client) -> None:
        self.client = client
        self.token = None
        self.trial_pub = client.declare_publisher(KEYS.topic("experiment/trial"))
        self.result_pub = client.declare_publisher(KEYS.topic("experiment/result"))
        self.seq = 0

    def alive(self, up: bool) -> None:
        if up and self.token is None:
            self.token = self.client.liveliness().declare_token(KEYS.alive("experiment"))
        elif not up and self.token is not None:
            self.token.undeclare()
            self.token = None

    def event(self, phase: str, trial: int, text: str = "") -> None:
        self.seq += 1
        msg = m.TrialEvent(seq=self.seq, t_ns=time.time_ns(), options=("red", "blue"),
                           phase=phase, trial=trial, mode="consensus", option="red", text=text,
                           session="S1")
        self.trial_pub.put(m.encode(msg))

    def result(self, trial: int, score: int) -> None:
        self.seq += 1
        msg = m.TrialResult(seq=self.seq, t_ns=time.time_ns(), options=("red", "blue"),
                            trial=trial, mode="consensus", option="red", robot="red",
                            human="red", outcome="C", score=score, session="S1")
        self.result_pub.put(m.encode(msg))


def _served_url(proc) -> str:
    found = re.search(r"serving (http://127\.0\.0\.1:\d+/)", proc.log_path.read_text())
    return found.group(1) if found else ""


def test_the_page_shows_countdown_go_and_points_and_waits_when_the_conductor_is_gone(
    router, client, spawn, browser, tmp_path
):
    display = spawn("display", "--http", "127.0.0.1:0")
    url = wait_for(lambda: _served_url(display) or (display.poll() is not None and "exited"),
                   30, "the display's URL in its log")
    assert url != "exited", display.log_path.read_text()[-2000:]
    wait_for(lambda: any(r.ok is not None for r in client.liveliness().get(
        KEYS.alive("display"), timeout=0.3)), 30, "the display up")
    conductor = Conductor(client)
    status = Collector(client, KEYS.topic("rig/status"), m.NodeStatus)

    def handled() -> int:  # messages the display took in, as its latest heartbeat counts them
        beats = [s for s in status.messages if s.service == "display"]
        return beats[-1].received if beats else 0

    browser.get(url)

    def screen() -> tuple[str, str, str]:  # what is drawn, in one WebDriver round trip
        kind, big, small = browser.execute_script(
            "return [document.body.dataset.screen, document.getElementById('big').innerText,"
            " document.getElementById('small').innerText];")
        return kind or "", big, small

    def shows(kind: str, big: str, small: str | None = None) -> bool:
        now = screen()
        return now[:2] == (kind, big) and (small is None or now[2] == small)

    latencies: list[float] = []  # event published → the browser shows it (s)

    def expect(kind: str, big: str, small: str | None = None) -> None:
        start = time.monotonic()
        wait_for(lambda: shows(kind, big, small), 10, f"{kind} {big!r} {small!r}, not {screen()}")
        latencies.append(time.monotonic() - start)

    expect("wait", "Please wait")  # no conductor yet
    conductor.alive(True)
    wait_for(lambda: "the conductor is up" in display.log_path.read_text(), 10,
             "the display seeing the conductor")
    for trial, score, total in ((1, 2, "Total: +2 points"), (2, 0, "Total: +2 points")):
        conductor.event("setup", trial, text="significant")  # the gaze level: never shown
        expect("ready", "Get ready")
        for word in ("1", "2", "3"):
            conductor.event("countdown", trial, text=word)
            expect("countdown", word)
        conductor.event("go", trial, text="go")
        expect("go", "GO")
        conductor.event("end", trial)
        expect("wait", "Please wait")
        conductor.result(trial, score)
        expect("score", "+2 points" if score == 2 else "0 points", total)
    browser.save_screenshot(str(tmp_path / "score.png"))
    shown = sorted(latencies[1:])  # the first is the page's own load
    print(f"event published → drawn in the browser: median {shown[len(shown) // 2] * 1e3:.0f} ms, "
          f"max {shown[-1] * 1e3:.0f} ms over {len(shown)} screens")
    assert not re.search(r"red|blue|consensus|significant|\bC\b", browser.page_source)

    # The conductor dies during a trial's go: the page must not keep saying "go".
    conductor.event("setup", 3)
    conductor.event("go", 3, text="go")
    expect("go", "GO")
    conductor.alive(False)
    expect("wait", "Please wait")
    conductor.event("go", 3, text="go")  # a late event of a conductor gone: still waits
    wait_for(lambda: handled() >= conductor.seq, 10, "the display's heartbeat counting the go")
    assert shows("wait", "Please wait"), screen()

    # The display service itself dies while the page shows go: its stream falls silent.
    conductor.alive(True)  # its token and its events travel apart: wait until the display knows
    wait_for(lambda: display.log_path.read_text().count("the conductor is up") == 2, 10,
             "the display seeing the conductor back")
    conductor.event("setup", 4)
    conductor.event("go", 4, text="go")
    expect("go", "GO")
    display.terminate()
    assert display.wait(10) == 0, display.log_path.read_text()[-2000:]
    expect("wait", "Please wait")


def test_the_page_says_thank_you_at_the_end_and_keeps_it_when_the_rig_stops(
    router, client, spawn, browser
):
    # The audit: the participant's page ended on "Please wait", not the "Thank you" the docs
    # promise: `nod run` stops the display with the rest of the rig, and the page took the lost
    # stream for "not sure what is true". The end of a session stays true.
    display = spawn("display", "--http", "127.0.0.1:0")
    url = wait_for(lambda: _served_url(display) or (display.poll() is not None and "exited"),
                   30, "the display's URL in its log")
    assert url != "exited", display.log_path.read_text()[-2000:]
    conductor = Conductor(client)
    conductor.alive(True)
    wait_for(lambda: "the conductor is up" in display.log_path.read_text(), 30,
             "the display seeing the conductor")
    browser.get(url)

    def screen() -> tuple[str, str, str]:
        kind, big, small = browser.execute_script(
            "return [document.body.dataset.screen, document.getElementById('big').innerText,"
            " document.getElementById('small').innerText];")
        return kind or "", big, small

    conductor.event("setup", 1)
    wait_for(lambda: screen()[:2] == ("ready", "Get ready"), 10, f"get ready, not {screen()}")
    conductor.event("go", 1, text="go")
    conductor.event("end", 1)
    conductor.result(1, 2)
    wait_for(lambda: screen()[0] == "score", 10, f"the points, not {screen()}")
    conductor.event("session_end", 1, text="complete")
    wait_for(lambda: screen() == ("done", "Thank you", "Total: +2 points"), 10,
             f"thank you, not {screen()}")
    conductor.alive(False)  # the conductor exits
    display.terminate()  # and the rig stops
    assert display.wait(10) == 0, display.log_path.read_text()[-2000:]
    time.sleep(4.0)  # a negative check: past the page's 3 s staleness bound, the stream gone
    assert screen() == ("done", "Thank you", "Total: +2 points"), screen()
