// fpv-station: voice callouts for a pilot who cannot look away from the picture (goggles),
// through the browser's own speech synthesis (window.speechSynthesis; nothing is sent
// anywhere). Said when it happens, from the page's one telemetry feed (telemetry.js):
//   link     "Link lost" / "Link regained"       (the OSD's LINK LOST rule)
//   armed    "Armed" / "Disarmed"
//   mode     "Altitude mode", ...
//   battery  "Battery low, 18 percent"            (below the OSD's LOW BATTERY level)
//   recording "Recording started" / "stopped"    (GET /api/status, telemetry.js)
//   task     "Next: climb to 4 m"                 (task-panel.js onTaskStep)
//   altitude "4 metres"                           (armed, at each multiple of the step)
// Link lost and arming cut short what is still being said; the rest queue. Nothing is
// said of the state the page found on opening, only of changes seen since.
//
// Off by default on the pilot page and on in goggles; each callout and the altitude step
// can be switched (a "Voice" menu in the header bar, or in the goggles' OSD menu), kept in
// localStorage ("fpv.voice"): {on, off: [callouts], altStepM}.
//   import { voiceControls } from "/voice.js";  parent.append(voiceControls());
import { expose } from "/debug.js";
import { $, el } from "/lib.js";
import { feed } from "/telemetry.js";
import { nextAction, onTaskStep } from "/task-panel.js";

const STORE_KEY = "fpv.voice";
const LOW_BATTERY_PCT = 20; // the OSD's LOW BATTERY (osd.js)
const REACHED_M = 0.3; // an altitude is said once the height is this close to it
const ALT_STEPS_M = [0, 1, 2, 5, 10]; // 0: no altitude callouts
export const CALLOUTS = {
  link: "link lost / regained",
  armed: "armed / disarmed",
  mode: "mode changes",
  battery: "low battery",
  recording: "recording started / stopped",
  task: "task step",
  altitude: "altitude",
};
// PX4's mode names as a pilot says them.
const SPOKEN_MODES = { POSCTL: "Position", ALTCTL: "Altitude", STABILIZED: "Stabilized", MANUAL: "Manual",
  "AUTO.LAND": "Land", LAND: "Land", "AUTO.RTL": "Return", RTL: "Return", "AUTO.LOITER": "Hold",
  LOITER: "Hold", "AUTO.TAKEOFF": "Takeoff", TAKEOFF: "Takeoff", "AUTO.MISSION": "Mission",
  MISSION: "Mission", OFFBOARD: "Offboard", ACRO: "Acro" };

const goggles = document.body.classList.contains("goggles-page");
const config = load();

function load() {
  const defaults = { on: goggles, off: [], altStepM: 5 };
  try {
    const saved = JSON.parse(localStorage.getItem(STORE_KEY) || "null");
    if (saved && typeof saved.on === "boolean" && Array.isArray(saved.off)) return { ...defaults, ...saved };
  } catch (err) { /* a broken entry: the defaults */ }
  return defaults;
}

function save() {
  localStorage.setItem(STORE_KEY, JSON.stringify(config));
  for (const sync of groups) sync();
}

export function say(kind, text, { urgent = false } = {}) {
  if (!config.on || config.off.includes(kind)) return;
  const synth = window.speechSynthesis;
  if (!synth || typeof SpeechSynthesisUtterance === "undefined") return;
  if (urgent) synth.cancel();
  const u = new SpeechSynthesisUtterance(text);
  u.rate = 1.15;
  synth.speak(u);
}

// -- what changed --------------------------------------------------------------------
// The last state seen: null until the vehicle was first heard (nothing said of it).
let seen = null;

function check() {
  const msg = feed.latest;
  const s = msg && msg.state;
  const heard = Boolean(s) && feed.flowing() && !s.link.link_lost;
  if (seen === null) {
    if (!heard) return;
    seen = { heard, armed: s.heartbeat.armed, mode: s.heartbeat.mode, low: lowBattery(s), level: null };
    return;
  }
  if (heard !== seen.heard) {
    seen.heard = heard;
    say("link", heard ? "Link regained" : "Link lost", { urgent: !heard });
  }
  if (!heard) return; // what a silent vehicle's last state says is not news
  const { armed, mode } = s.heartbeat;
  if (armed !== seen.armed) {
    seen.armed = armed;
    seen.level = null;
    say("armed", armed ? "Armed" : "Disarmed", { urgent: true });
  }
  if (mode && mode !== seen.mode) {
    seen.mode = mode;
    say("mode", `${SPOKEN_MODES[mode] ?? mode} mode`);
  }
  const low = lowBattery(s);
  if (low && !seen.low) say("battery", `Battery low, ${Math.round(s.battery.remaining_pct)} percent`);
  seen.low = low;
  const alt = s.altitude.relative_alt_m;
  const step = config.altStepM;
  if (armed && step > 0 && alt !== null && alt !== undefined) {
    const level = Math.round(alt / step);
    if (seen.level === null) seen.level = level; // where it was when armed: not news
    else if (level !== seen.level && Math.abs(alt - level * step) <= REACHED_M) {
      seen.level = level;
      say("altitude", `${level * step} metres`);
    }
  }
}

const lowBattery = (s) => s.battery.remaining_pct !== null && s.battery.remaining_pct < LOW_BATTERY_PCT;

let pending = false;
window.addEventListener("fpv:telemetry", () => {
  if (pending) return;
  pending = true;
  setTimeout(() => { pending = false; check(); }, 100); // at most ten checks a second
});
setInterval(check, 500); // no message at all is news too (link lost)

let recording = null;
// What the callouts start from: the vehicle first heard, the recording state first read.
expose("voice", { get heard() { return seen !== null; }, get recording() { return recording; } });
window.addEventListener("fpv:status", (e) => {
  const rec = e.detail && e.detail.recording;
  if (!rec) return;
  if (recording !== null && rec.recording !== recording) {
    say("recording", rec.recording ? "Recording started" : "Recording stopped");
  }
  recording = rec.recording;
});

let step = null;
onTaskStep((next) => {
  if (next && next !== step) say("task", `Next: ${nextAction(next)}`);
  step = next;
});

// -- the switches ----------------------------------------------------------------------
const groups = []; // each group's sync(): every menu shows the one config

export function voiceControls() {
  const master = el("input", { type: "checkbox", "data-voice": "on" });
  master.addEventListener("change", () => { config.on = master.checked; save(); });
  const boxes = Object.entries(CALLOUTS).map(([kind, label]) => {
    const box = el("input", { type: "checkbox", "data-voice": kind });
    box.addEventListener("change", () => {
      config.off = box.checked ? config.off.filter((k) => k !== kind) : [...config.off, kind];
      save();
    });
    return [box, el("label", {}, box, ` ${label}`)];
  });
  const stepSelect = el("select", { "data-voice": "alt-step", title: "altitude callouts every" },
    ...ALT_STEPS_M.map((m) => el("option", { value: String(m) }, m ? `every ${m} m` : "no altitude")));
  stepSelect.addEventListener("change", () => { config.altStepM = Number(stepSelect.value); save(); });
  const summary = el("summary", {}, "Voice");
  const box = el("details", { class: "voice-menu" }, summary,
    el("div", { class: "voice-body" }, el("label", {}, master, " speak callouts"),
      ...boxes.map(([, label]) => label), stepSelect));
  const sync = () => {
    master.checked = config.on;
    for (const [b] of boxes) { b.checked = !config.off.includes(b.dataset.voice); b.disabled = !config.on; }
    stepSelect.value = String(config.altStepM);
    stepSelect.disabled = !config.on;
    summary.textContent = `Voice: ${config.on ? "on" : "off"}`;
  };
  groups.push(sync);
  sync();
  return box;
}

const home = $("toolbar") || document.querySelector(".osd-menu");
if (home) home.append(voiceControls());
