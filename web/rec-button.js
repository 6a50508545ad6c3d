// fpv-station recording control for the pilot page: the REC button (#rec-button in the
// header bar) with an indicator and the elapsed time. State from GET /api/recording (once
// a second); start/stop by POST (the control token, when the station has one, is asked
// for by lib.js).
import { $, el, api } from "/lib.js";
import { feed } from "/telemetry.js";
import { toast } from "/toast.js";

const POLL_MS = 1000;
let status = null; // newest GET /api/recording reply
let statusAt = 0; // performance.now() when it arrived
let busy = false;

const button = $("rec-button");
const label = el("span", { id: "rec-label" }, "REC");
button.replaceChildren(el("span", { class: "rec-dot" }), " ", label);

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
    // elapsed_s is in the source's time (a replay's log time): it runs on at its rate.
    const elapsed = status.elapsed_s + feed.sourceSeconds(performance.now() - statusAt);
    button.className = "recording";
    label.textContent = `STOP ${fmtElapsed(elapsed)}`;
    const dropped = Object.values(status.frames_dropped).reduce((a, b) => a + b, 0);
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

function took(reply) {
  status = reply;
  statusAt = performance.now();
}

async function poll() {
  try {
    took(await api("/api/recording"));
  } catch (err) {
    status = null;
  }
  render();
}

button.addEventListener("click", async () => {
  if (busy) return;
  busy = true;
  button.disabled = true;
  try {
    took(await api(status && status.recording ? "/api/recording/stop" : "/api/recording/start",
      { method: "POST" }));
  } catch (err) {
    toast(`Recording: ${err.message}`, { bad: true });
  } finally {
    busy = false;
    button.disabled = false;
    render();
  }
});

poll();
setInterval(poll, POLL_MS);
setInterval(render, 250); // the elapsed time ticks between polls
