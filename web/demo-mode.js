// fpv-station pilot page: demonstration mode (server/demo_mode.py). The pilot chooses the
// task in the task panel, enters their name and how many attempts, and starts a run
// (POST /api/demo); each attempt is one recorded session tagged with the pilot's name and
// "human" in its session.json. A drop-down in the header bar shows "attempt k of N" (and
// REC while that attempt is recorded), each attempt flown with whether it counts (the
// station's score at the disarm), and ends the run early (DELETE /api/demo). The run is
// the server's: a reloaded page shows it as it was (GET /api/demo, every 2 s).
import { $, el, api, ApiError } from "/lib.js";
import { toast } from "/toast.js";

const POLL_MS = 2000;
let state = null; // the newest GET /api/demo reply

const summary = el("summary", { id: "demo-summary", title: "Demonstration mode" }, "Demo");
const name = el("input", { id: "demo-pilot", type: "text", maxlength: 40, autocomplete: "name",
  placeholder: "pilot's name", required: true });
const count = el("input", { id: "demo-attempts", type: "number", min: 1, max: 50, value: 5, required: true });
const start = el("button", { id: "demo-start", type: "submit" }, "Start");
const form = el("form", { id: "demo-form" },
  el("label", {}, "Pilot ", name), el("label", {}, "Attempts ", count), start);
const status = el("p", { id: "demo-status", class: "note" });
const stop = el("button", { id: "demo-end", type: "button", hidden: true }, "End run");
const flown = el("ol", { id: "demo-flown", class: "demo-flown" });
const menu = el("details", { id: "demo-menu", class: "demo-menu" }, summary,
  el("div", { class: "demo-body" }, form, status, stop, flown));

form.addEventListener("submit", async (ev) => {
  ev.preventDefault();
  try {
    state = await api("/api/demo", { method: "POST",
      body: { pilot: name.value, attempts: Number(count.value) } });
    localStorage.setItem("fpv.demo.pilot", state.run.pilot);
  } catch (err) {
    if (err instanceof ApiError) toast(`Demonstration not started: ${err.message}`, { bad: true });
  }
  render();
});

stop.addEventListener("click", async () => {
  try {
    state = await api("/api/demo", { method: "DELETE" });
  } catch (err) {
    if (err instanceof ApiError) toast(`Run not ended: ${err.message}`, { bad: true });
  }
  render();
});

function render() {
  const run = state && state.run;
  const active = Boolean(state && state.active);
  form.hidden = active;
  stop.hidden = !active;
  menu.classList.toggle("active", active);
  menu.classList.toggle("recording", active && state.recording);
  if (active) {
    summary.textContent = `DEMO ${run.pilot}: attempt ${state.attempt} of ${run.attempts}` +
      (state.recording ? " REC" : "");
    status.textContent = `Task ${run.task_id}. ${run.task_name}: each recorded session is one attempt.`;
  } else {
    summary.textContent = "Demo";
    status.textContent = run
      ? `Last run: ${run.pilot}, ${run.sessions.length} of ${run.attempts} flown (${run.ended}).`
      : "Choose the task, then enter your name and the number of attempts.";
  }
  count.max = state ? state.max_attempts : 50;
  flown.replaceChildren(...(state ? state.flown : []).map((a) => el("li", {
    "data-counts": a.counts == null ? "pending" : String(a.counts),
    title: a.why || "",
  }, `${a.session}: ${a.counts == null ? "scoring..." : a.counts ? "counts" : "does not count"}`)));
}

async function poll() {
  try {
    state = await api("/api/demo");
  } catch {
    // unreachable or no recorder: keep the last state shown
  }
  render();
  setTimeout(poll, POLL_MS);
}

name.value = localStorage.getItem("fpv.demo.pilot") || "";
const home = $("toolbar");
if (home) home.append(menu);
poll();
