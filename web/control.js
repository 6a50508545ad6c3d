// fpv-station stick control for the digital twin: gamepad (Gamepad API) or keyboard,
// sent at 50 Hz over WS /ws/control; the station turns it into MANUAL_CONTROL. Only shown
// when the station runs the twin (GET /api/status -> source "sim"): the station never
// sends stick inputs to a real vehicle. Sticks stop with the page, the socket or the tab
// going to background: the station's dead-man (0.5 s) then centres them (= hold).
//
// Keyboard (Position mode: released keys = hold): W/S pitch, A/D roll, Q/E yaw,
// ArrowUp/ArrowDown climb/descend (R/F too); Shift = full deflection. Arm: ArrowDown+E
// (throttle down, yaw right); disarm: ArrowDown+Q. "?" shows the key legend.
// Sticks are centred (hold) while the window has no focus or the tab is hidden.
// Touch (phones, tablets): two virtual sticks, Mode 2 (touch-sticks.js); left stick to
// the bottom-right corner arms, bottom-left disarms.
// Gamepad: axis mapping, inversion and calibration are kept in localStorage
// ("fpv.control.gamepad"); default = Mode 2 on a standard pad (left: yaw/throttle,
// right: roll/pitch).
// A station with a control token refuses the socket (close 4401): lib.js asks for the
// token and the socket opens again with it. The sticks are one page's at a time: a page
// that connects while another has them is told so (a toast), and its commands other than
// Disarm, Land and RTL are refused (server/routes/control.py).
// The gamepad panel shows every axis of the pad and the four sticks sent, live (the send
// rate). Every command's answer is a toast: done, or refused with the vehicle's (or the
// station's) reason. The arming gesture on the keys turns the sticks on by itself.
import { expose } from "/debug.js";
import { $, el, svgEl, askToken, wsUrl, CLOSE_UNAUTHORIZED } from "/lib.js";
import { feed } from "/telemetry.js";
import { mountTouchSticks, touchDevice } from "/touch-sticks.js";
import { toast } from "/toast.js";

const RATE_MS = 20;
const STORE_KEY = "fpv.control.gamepad";
const FUNCS = ["roll", "pitch", "yaw", "throttle"];
const DEFAULT_MAP = {
  roll: { index: 2, invert: false }, pitch: { index: 3, invert: true },
  yaw: { index: 0, invert: false }, throttle: { index: 1, invert: true },
};
// enabled: the socket is open; held: this page has the sticks (another page may have them)
const ctl = { enabled: false, held: false, sticks: null, input: "keyboard", lastReply: null };
expose("control", ctl);

let config = loadConfig();
let socket = null;
let timer = null;
let calibrating = null; // {min: [], max: []} while the user sweeps the sticks
const keys = new Set();
let sentRows = {}; // the gamepad panel's rows of the sticks sent, by function
const touch = mountTouchSticks(document.body);

// ---- widget in the toolbar ----
const box = $("control-widget");
box.innerHTML = `
  <button type="button" id="ctl-toggle" title="fly the twin from this browser">Sticks: off</button>
  <span id="ctl-input" class="pill">keyboard</span>
  <button type="button" id="ctl-arm">Arm</button>
  <button type="button" id="ctl-disarm">Disarm</button>
  <select id="ctl-mode" title="flight mode">
    <option value="POSCTL">Position</option><option value="ALTCTL">Altitude</option>
    <option value="STABILIZED">Stabilized</option></select>
  <button type="button" id="ctl-reset" title="back on the start pad">Reset</button>
  <details id="ctl-pad"><summary>Gamepad</summary><div id="ctl-pad-body"></div></details>`;

$("ctl-toggle").onclick = () => (ctl.enabled ? stop() : start());
$("ctl-arm").onclick = () => command({ type: "arm" });
$("ctl-disarm").onclick = () => command({ type: "disarm" });
$("ctl-reset").onclick = () => command({ type: "reset" });
$("ctl-mode").onchange = (e) => command({ type: "mode", mode: e.target.value });
renderPadPanel();

// The sticks fly the digital twin: shown when the station's source is the sim, from the
// page's one GET /api/status poll (telemetry.js), not a second fetch of the same route.
const showForSim = (st) => { if (st) box.hidden = st.source !== "sim"; };
showForSim(feed.status);
window.addEventListener("fpv:status", (e) => showForSim(e.detail));

// ---- connection ----
function start() {
  const ws = (socket = new WebSocket(wsUrl("/ws/control", { auth: true })));
  ws.onmessage = (ev) => {
    let msg;
    try { msg = JSON.parse(ev.data); } catch (err) { return; }
    ctl.lastReply = msg;
    if (msg.type === "hello" && msg.sticks === false) {
      // Another page has the sticks: this one sends none, its emergencies still go.
      ctl.held = false;
      clearInterval(timer);
      timer = null;
      touch.show(false);
      $("ctl-toggle").textContent = "Sticks: taken";
      $("ctl-toggle").classList.remove("on");
      toast("Another page has the sticks: from here only Disarm, Land and RTL.", { bad: true });
    }
    if (msg.type === "ack") showAck(msg);
    if (msg.error) toast(msg.error_msg, { bad: true });
  };
  ws.onopen = () => {
    ctl.enabled = ctl.held = true;
    $("ctl-input").className = "pill";
    $("ctl-toggle").textContent = "Sticks: on";
    $("ctl-toggle").classList.add("on");
    timer = setInterval(tick, RATE_MS);
    touch.show(touchDevice());
  };
  ws.onclose = (ev) => {
    if (ws !== socket) return; // an old socket, already replaced
    stop();
    if (ev.code !== CLOSE_UNAUTHORIZED) return;
    if (askToken()) start();
    else { waiting.forEach(clearTimeout); waiting.clear(); }
  };
}

function stop() {
  ctl.enabled = ctl.held = false;
  clearInterval(timer);
  timer = null;
  if (socket && socket.readyState <= 1) socket.close();
  socket = null;
  touch.show(false);
  $("ctl-toggle").textContent = "Sticks: off";
  $("ctl-toggle").classList.remove("on");
}

// A command before the sticks are on opens the socket and waits for it (3 s at most);
// a declined token drops the commands waiting (their retries would ask again).
const waiting = new Set(); // retry timers of commands waiting for the socket
function command(msg, tries = 10) {
  if (socket && socket.readyState === 1) return socket.send(JSON.stringify(msg));
  if (!socket) start();
  if (tries > 0) {
    const retry = setTimeout(() => { waiting.delete(retry); command(msg, tries - 1); }, 300);
    waiting.add(retry);
  }
}

// The vehicle's answer to arm, disarm, mode, land: done, or refused and why.
function showAck(msg) {
  if (msg.ok) { toast(`${msg.cmd}: done`); return; }
  const why = msg.text ? `: ${msg.text}` : "";
  toast(`${msg.cmd} refused (${msg.result ?? "no answer"})${why}`, { bad: true });
}

function tick() {
  const pad = firstGamepad();
  // A gamepad wins; touch sticks once a finger has moved them and no key is held.
  const input = pad ? "gamepad" : touch.touched && keys.size === 0 ? "touch" : "keyboard";
  const sticks = released() ? { ...CENTRED }
    : input === "gamepad" ? fromGamepad(pad) : input === "touch" ? touch.read() : fromKeyboard();
  ctl.input = input;
  ctl.sticks = sticks;
  if (calibrating && pad) sweep(pad);
  const pill = $("ctl-input");
  if (!pill.classList.contains("bad")) {
    // Some browsers offer gamepads only to secure pages (https or localhost).
    const noPads = !navigator.getGamepads && !window.isSecureContext;
    const text = pad ? pad.id.slice(0, 24) : input === "touch" ? "touch"
      : noPads ? "keyboard (gamepad needs https)" : "keyboard";
    if (pill.textContent !== text) pill.textContent = text;
  }
  if (ctl.held && socket && socket.readyState === 1) socket.send(JSON.stringify({ type: "sticks", ...sticks }));
  if ($("ctl-pad").open) drawBars(pad, sticks);
}

// ---- inputs ----
const clamp = (v, lo, hi) => Math.min(hi, Math.max(lo, v));
function fromKeyboard() {
  const k = (code) => keys.has(code);
  const amount = k("ShiftLeft") || k("ShiftRight") ? 1.0 : 0.6;
  const axis = (plus, minus) => (plus.some(k) ? amount : 0) - (minus.some(k) ? amount : 0);
  const sticks = {
    roll: axis(["KeyD"], ["KeyA"]), pitch: axis(["KeyW"], ["KeyS"]),
    yaw: axis(["KeyE"], ["KeyQ"]),
    throttle: clamp(0.5 + 0.5 * axis(["ArrowUp", "KeyR"], ["ArrowDown", "KeyF"]), 0, 1),
  };
  // The stick gestures are full deflections (the twin wants throttle < 0.1 and |yaw| > 0.9):
  // throttle down with yaw right arms, with yaw left disarms, with or without Shift.
  const down = ["ArrowDown", "KeyF"].some(k), up = ["ArrowUp", "KeyR"].some(k);
  if (down && !up && (k("KeyE") !== k("KeyQ"))) {
    sticks.throttle = 0;
    sticks.yaw = k("KeyE") ? 1 : -1;
  }
  return sticks;
}

// Sticks let go (hold) while the page is not the pilot's focus: a gamepad keeps reporting
// its axes to a background tab, and nobody is watching the video then. Focus in a frame of
// the page (the 3D panel's viewer) is still the page's (document.hasFocus()), though the
// window's blur fires: the keys go to the frame then, the gamepad flies on.
const CENTRED = { roll: 0, pitch: 0, yaw: 0, throttle: 0.5 };
window.addEventListener("blur", () => touch.release());
document.addEventListener("visibilitychange", () => {
  if (document.visibilityState !== "visible") { keys.clear(); touch.release(); }
});
const released = () => !document.hasFocus() || document.visibilityState !== "visible";

function firstGamepad() {
  const pads = navigator.getGamepads ? navigator.getGamepads() : [];
  for (const p of pads) if (p && p.connected && p.axes.length >= 4) return p;
  return null;
}

function axisValue(pad, f) {
  const m = config.map[f];
  const raw = pad.axes[m.index] ?? 0;
  const c = config.calib[m.index] || { center: 0, min: -1, max: 1 };
  let v = raw >= c.center ? (raw - c.center) / Math.max(c.max - c.center, 1e-3)
                          : (raw - c.center) / Math.max(c.center - c.min, 1e-3);
  v = clamp(v, -1, 1);
  return m.invert ? -v : v;
}

function fromGamepad(pad) {
  const s = {};
  for (const f of FUNCS) s[f] = axisValue(pad, f);
  s.throttle = clamp(0.5 + 0.5 * s.throttle, 0, 1); // spring-centred stick: centre = hold
  return s;
}

function sweep(pad) {
  pad.axes.forEach((v, i) => {
    calibrating.min[i] = Math.min(calibrating.min[i] ?? v, v);
    calibrating.max[i] = Math.max(calibrating.max[i] ?? v, v);
  });
}

// ---- gamepad mapping and calibration, saved in the browser ----
function loadConfig() {
  try {
    const saved = JSON.parse(localStorage.getItem(STORE_KEY) || "null");
    if (saved && saved.map && FUNCS.every((f) => saved.map[f])) return { calib: {}, ...saved };
  } catch (err) { /* a broken entry falls back to the defaults */ }
  return { map: JSON.parse(JSON.stringify(DEFAULT_MAP)), calib: {} };
}

function saveConfig() {
  localStorage.setItem(STORE_KEY, JSON.stringify(config));
}

function renderPadPanel() {
  const body = $("ctl-pad-body");
  body.innerHTML = FUNCS.map((f) => `
    <label>${f}: axis <input type="number" min="0" max="15" data-f="${f}" data-k="index"
      value="${config.map[f].index}">
      <input type="checkbox" data-f="${f}" data-k="invert" ${config.map[f].invert ? "checked" : ""}> invert</label>`).join("") +
    `<button type="button" id="ctl-cal">${calibrating ? "Done (centre sticks)" : "Calibrate"}</button>
     <button type="button" id="ctl-defaults">Defaults</button>
     <table id="ctl-bars" aria-label="live axes"><tbody id="ctl-bars-sent"></tbody>
       <tbody id="ctl-bars-pad"></tbody></table>`;
  sentRows = Object.fromEntries(FUNCS.map((f) => [f, barRow(`sent-${f}`, `sent ${f}`)]));
  $("ctl-bars-sent").append(...Object.values(sentRows));
  body.querySelectorAll("input").forEach((el) => {
    el.onchange = () => {
      const m = config.map[el.dataset.f];
      if (el.dataset.k === "index") m.index = clamp(parseInt(el.value, 10) || 0, 0, 15);
      else m.invert = el.checked;
      saveConfig();
    };
  });
  $("ctl-cal").onclick = () => {
    const pad = firstGamepad();
    if (!calibrating) {
      calibrating = { min: [], max: [] }; // move every stick to its ends, then press Done
    } else if (pad) {
      pad.axes.forEach((v, i) => {
        config.calib[i] = { center: v, min: calibrating.min[i] ?? -1, max: calibrating.max[i] ?? 1 };
      });
      calibrating = null;
      saveConfig();
    } else {
      calibrating = null;
    }
    renderPadPanel();
  };
  $("ctl-defaults").onclick = () => {
    config = { map: JSON.parse(JSON.stringify(DEFAULT_MAP)), calib: {} };
    saveConfig();
    renderPadPanel();
  };
}

// ---- live axis bars (the gamepad panel): each pad axis, and what the station is sent ----
function barRow(name, label) {
  const svg = svgEl("svg", { viewBox: "-1 0 2 1", preserveAspectRatio: "none", class: "axis-bar" },
    svgEl("rect", { x: 0, y: 0.15, width: 0, height: 0.7 }), svgEl("path", { d: "M0 0V1" }));
  const value = el("td", { class: "num" }, "--");
  return el("tr", { "data-bar": name }, el("th", {}, label), el("td", {}, svg), value);
}

// v in -1..1: the bar runs from the centre to v.
function setBar(row, v, text = v === null || v === undefined ? "--" : v.toFixed(2)) {
  const cell = row.lastChild;
  if (cell.textContent === text) return;
  cell.textContent = text;
  const rect = row.querySelector("rect");
  const x = clamp(v ?? 0, -1, 1);
  rect.setAttribute("x", String(Math.min(0, x)));
  rect.setAttribute("width", String(Math.abs(x)));
}

function drawBars(pad, sticks) {
  const padBody = $("ctl-bars-pad");
  const axes = pad ? pad.axes : [];
  if (padBody.children.length !== axes.length) {
    padBody.replaceChildren(...axes.map((_, i) => barRow(`axis-${i}`, `axis ${i}`)));
  }
  axes.forEach((v, i) => setBar(padBody.children[i], v));
  // Throttle is sent as 0..1 (0.5 = hold): its bar shows it around the hold point.
  for (const f of FUNCS) {
    const v = f === "throttle" ? 2 * sticks.throttle - 1 : sticks[f];
    setBar(sentRows[f], v, sticks[f].toFixed(2));
  }
}

// Text fields keep their keys; a focused <select> (the task, a mode) does not get the
// arrow keys while the sticks are active: they fly, they never change a selection.
const typing = (e) => ["INPUT", "TEXTAREA"].includes(e.target.tagName) && e.target.type !== "checkbox";
// Keys are followed with the sticks off too: the arming gesture (down + E) turns them on,
// and the keys still held then arm.
const ARM_GESTURE = () => (keys.has("ArrowDown") || keys.has("KeyF")) && keys.has("KeyE");
window.addEventListener("keydown", (e) => {
  if (typing(e)) return;
  if (!ctl.enabled) {
    if (box.hidden || e.target.tagName === "SELECT") return;
    keys.add(e.code);
    if (ARM_GESTURE() && !socket) start();
    return;
  }
  if (e.target.tagName === "SELECT" && !e.code.startsWith("Arrow")) return;
  keys.add(e.code);
  if (e.code.startsWith("Arrow")) e.preventDefault();
}, { capture: true });
window.addEventListener("keyup", (e) => keys.delete(e.code));
window.addEventListener("blur", () => keys.clear()); // released keys must not stay held

// ---- the key legend ("?") ----
const LEGEND = [
  ["Sticks: off", "the button turns the sticks on (keys, gamepad, touch); the arming gesture \u2193 + E does too"],
  ["W / S", "pitch forward / back"], ["A / D", "roll left / right"], ["Q / E", "yaw left / right"],
  ["\u2191 / \u2193 (R / F)", "climb / descend"], ["Shift", "full deflection"],
  ["\u2193 + E", "arm (throttle down, yaw right); turns the sticks on when off"], ["\u2193 + Q", "disarm (throttle down, yaw left)"],
  ["touch", "left stick: throttle / yaw (throttle stays), right: pitch / roll"],
  ["touch \u2198", "left stick bottom-right: arm; bottom-left: disarm"],
  ["?", "this legend"],
];
const legend = el("div", { id: "key-legend", class: "key-legend", role: "dialog", "aria-label": "keys", hidden: true },
  el("h2", {}, "Keys (flying the twin)"),
  el("table", {}, ...LEGEND.map(([key, what]) => el("tr", {}, el("th", {}, key), el("td", {}, what)))));
legend.addEventListener("click", () => { legend.hidden = true; });
document.body.append(legend);
window.addEventListener("keydown", (e) => {
  if (typing(e)) return;
  if (e.key === "?") legend.hidden = !legend.hidden;
  else if (e.key === "Escape") legend.hidden = true;
});
