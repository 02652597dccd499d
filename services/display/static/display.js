// The participant's screen: draws each screen that /events sends, and says "Please wait"
// whenever it cannot be sure what is true now — the stream is lost, silent for STALE_MS (the
// server repeats the current screen every second), or sent something it does not know. The end
// of a session ("done": Thank you, the total) stays true after the rig stops: it is kept when
// the stream goes, until the server sends another screen (the next participant's).
"use strict";
(() => {
  const STALE_MS = 3000;
  const REOPEN_MS = 1000; // after the browser gave the stream up (an error status)
  const KINDS = new Set(["wait", "ready", "countdown", "go", "score", "done"]);
  const WAIT = { kind: "wait", big: "Please wait", small: "" };
  const big = document.getElementById("big");
  const small = document.getElementById("small");
  let staleTimer = 0;
  let shown = WAIT;

  function lost() {
    if (shown.kind !== "done") show(WAIT);
  }

  function show(screen) {
    const ok = screen && KINDS.has(screen.kind) && typeof screen.big === "string"
      && typeof screen.small === "string";
    const s = ok ? screen : WAIT;
    shown = s;
    document.body.dataset.screen = s.kind;
    big.textContent = s.big;
    small.textContent = s.small;
    document.title = s.big;
  }

  function heard() {
    clearTimeout(staleTimer);
    staleTimer = setTimeout(lost, STALE_MS);
  }

  function open() {
    const stream = new EventSource("/events");
    stream.onmessage = (event) => {
      heard();
      let screen = null;
      try {
        screen = JSON.parse(event.data);
      } catch (_) {
        screen = null;
      }
      show(screen);
    };
    stream.onerror = () => {
      lost();
      if (stream.readyState === EventSource.CLOSED) {
        stream.close();
        setTimeout(open, REOPEN_MS);
      }
    };
  }

  show(WAIT);
  heard();
  open();
})();
