// fpv-station recording control for the pilot page: a REC button with an indicator and
// the elapsed time, in the header bar (#toolbar). State from GET /api/recording (once a
// second); start/stop by POST. When the station has a control token, the first refused
// request asks for it once and keeps it in localStorage.
"use strict";

(() => {
  const POLL_MS = 1000;
  const TOKEN_KEY = "fpv.token";
  let status = null; // newest GET /api/recording reply
  let statusAt = 0; // performance.now() when it arrived
  let busy = false;

  const toolbar = document.getElementById("toolbar") || document.body;
  let button = document.getElementById("rec-button");
  if (!button) {
    button = document.createElement("button");
    button.id = "rec-button";
    toolbar.appendChild(button);
  }
  button.type = "button";
  button.innerHTML = '<span class="rec-dot"></span> <span id="rec-label">REC</span>';
  const label = button.querySelector("#rec-label");
  if (!document.getElementById("sessions-link")) {
    const a = document.createElement("a");
    a.id = "sessions-link";
    a.href = "/sessions.html";
    a.textContent = "Sessions";
    a.className = "toolbar-link";
    toolbar.appendChild(a);
  }

  const style = document.createElement("style");
  style.textContent = `
    #rec-button .rec-dot { display: inline-block; width: .7rem; height: .7rem;
      border-radius: 50%; background: #8a939c; vertical-align: middle; }
    #rec-button.recording { border-color: #ff3b30; color: #fff; background: #4a1512; }
    #rec-button.recording .rec-dot { background: #ff3b30; animation: rec-blink 1s steps(2) infinite; }
    #rec-button.error .rec-dot { background: #ffb020; }
    #rec-label { font-variant-numeric: tabular-nums; }
    .toolbar-link { color: #4aa3ff; font-size: .9rem; }
    @keyframes rec-blink { to { opacity: .2; } }`;
  document.head.appendChild(style);

  function authHeaders() {
    const token = localStorage.getItem(TOKEN_KEY);
    return token ? { Authorization: `Bearer ${token}` } : {};
  }

  function fmtElapsed(s) {
    s = Math.max(0, Math.floor(s));
    const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = s % 60;
    const mm = String(m).padStart(2, "0"), ss = String(sec).padStart(2, "0");
    return h ? `${h}:${mm}:${ss}` : `${mm}:${ss}`;
  }

  function render() {
    if (!status) {
      button.className = "error";
      label.textContent = "REC ?";
      button.title = "Recording status unknown (station unreachable)";
      return;
    }
    if (status.recording) {
      const elapsed = status.elapsed_s + (performance.now() - statusAt) / 1000;
      button.className = "recording";
      label.textContent = `STOP ${fmtElapsed(elapsed)}`;
      const dropped = Object.values(status.frames_dropped || {}).reduce((a, b) => a + b, 0);
      button.title = `Recording ${status.id} (${status.trigger})` +
        (dropped ? `; ${dropped} frames dropped` : "") +
        (status.stopping_at_wall ? "; stopping after the post-disarm tail" : "");
    } else {
      button.className = "";
      label.textContent = "REC";
      const last = status.last_stop;
      button.title = last ? `Last session ${last.id}: ${last.reason}` : "Start recording";
      if (last && last.reason.startsWith("disk full")) button.className = "error";
      if (status.last_error) {
        button.className = "error";
        button.title = `Recording could not start: ${status.last_error}`;
      }
    }
  }

  async function poll() {
    try {
      const r = await fetch("/api/recording", { cache: "no-store" });
      if (r.ok) {
        status = await r.json();
        statusAt = performance.now();
      } else {
        status = null;
      }
    } catch (err) {
      status = null;
    }
    render();
  }

  async function post(path) {
    let r = await fetch(path, { method: "POST", headers: authHeaders() });
    if (r.status === 401) {
      const token = prompt("This station needs its control token:");
      if (!token) return;
      localStorage.setItem(TOKEN_KEY, token);
      r = await fetch(path, { method: "POST", headers: authHeaders() });
    }
    if (r.ok) {
      status = await r.json();
      statusAt = performance.now();
    } else {
      const body = await r.json().catch(() => ({}));
      alert(`Recording: ${body.error_msg || r.statusText}`);
    }
  }

  button.addEventListener("click", async () => {
    if (busy) return;
    busy = true;
    button.disabled = true;
    try {
      await post(status && status.recording ? "/api/recording/stop" : "/api/recording/start");
    } finally {
      busy = false;
      button.disabled = false;
      render();
    }
  });

  poll();
  setInterval(poll, POLL_MS);
  setInterval(render, 250); // the elapsed time ticks between polls
})();
