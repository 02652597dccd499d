// The participant's screen: draws each screen that /events sends, and says "Please wait"
// whenever it cannot be sure what is true now — the stream is lost, silent for STALE_MS (the
// server repeats the current screen every second), or sent something it does not know.
"use strict";
(() => {
  const STALE_MS = 3000;
  const REOPEN_MS = 1000; // after the browser gave the stream up (an error status)
  const KINDS = new Set(["wait", "ready", "countdown", "go", "score", "done"]);
  const WAIT = { kind: "wait", big: "Please wait", small: "" };
  const big = document.getElementById("big");
  const small = document.getElementById("small");
  let staleTimer = 0;

  function show(screen) {
    const ok = screen && KINDS.has(screen.kind) && typeof screen.big === "string"
      && typeof screen.small === "string";
    const s = ok ? screen : WAIT;
    document.body.dataset.screen = s.kind;
    big.textContent = s.big;
    small.textContent = s.small;
    document.title = s.big;
  }

  function heard() {
    clearTimeout(staleTimer);
    staleTimer = setTimeout(() => show(WAIT), STALE_MS);
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
      show(WAIT);
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
