// fpv-station: Disarm, Land and RTL on every page (pilot, goggles' OSD menu, sessions,
// analysis, replay), for the digital twin and for a real vehicle on a live link (GET
// /api/status `control` "twin" or "emergency"; not for a replay or no link). They go
// through the pilot page's route and token (WS /ws/control, server/routes/control.py) to
// the followed vehicle, carried out whoever has the twin's sticks: an emergency is never
// refused for want of them. Disarm in flight (armed and
// not on the ground) stops the motors: the page asks first, then forces it (the
// vehicle's force magic). Each answer is a toast (toast.js): done, or refused and why.
//
//   import { emergencyButtons } from "/emergency.js";
//   parent.append(emergencyButtons());   // another group (the goggles' right eye menu)
// Loaded as a module it puts one group in the page's header bar, else its OSD menu.
import { $, el, api, askToken, wsUrl, CLOSE_UNAUTHORIZED } from "/lib.js";
import { toast } from "/toast.js";

const AIRBORNE_M = 0.5; // above this (relative altitude) an armed vehicle is in flight
const STATUS_MS = 5000; // whether the station flies the twin: asked this often
const OPEN_WAIT_MS = 3000;
// The socket stays open this long after the last command (for its answer and the next
// emergency), then gives its place back: the station has few control places.
const IDLE_CLOSE_MS = 30000;

const groups = [];
let commandable = false; // the station has a vehicle to command
let socket = null;
let opening = null; // Promise of the open socket
let idleTimer = null;

export function emergencyButtons() {
  const group = el("span", { class: "emergency", role: "group", "aria-label": "emergency", hidden: !commandable });
  const button = (type, label, title) => {
    const b = el("button", { type: "button", "data-emergency": type, title }, label);
    b.addEventListener("click", (e) => { e.stopPropagation(); act(type); });
    return b;
  };
  group.append(
    button("disarm", "Disarm", "Disarm now (in flight: asks, then stops the motors)"),
    button("land", "Land", "Land where it is"),
    button("rtl", "RTL", "Return to launch and land"),
  );
  groups.push(group);
  return group;
}

function open() {
  if (socket && socket.readyState === WebSocket.OPEN) return Promise.resolve(socket);
  if (opening) return opening;
  opening = new Promise((resolve, reject) => {
    const ws = new WebSocket(wsUrl("/ws/control", { auth: true }));
    const timer = setTimeout(() => reject(new Error("the station did not answer")), OPEN_WAIT_MS);
    ws.onmessage = (ev) => {
      let msg;
      try { msg = JSON.parse(ev.data); } catch (err) { return; }
      if (msg.type === "hello") { clearTimeout(timer); socket = ws; resolve(ws); return; }
      if (msg.type === "ack") {
        const why = msg.text ? `: ${msg.text}` : "";
        let text = `${msg.cmd}: done`;
        if (msg.result === "NO_ANSWER") text = `${msg.cmd}: no answer from the vehicle${why}`;
        else if (!msg.ok) text = `${msg.cmd} refused (${msg.result ?? "no answer"})${why}`;
        toast(text, { bad: !msg.ok });
      } else if (msg.error) {
        toast(msg.error_msg, { bad: true });
      }
    };
    ws.onclose = (ev) => {
      clearTimeout(timer);
      if (socket === ws) socket = null;
      reject(Object.assign(new Error(ev.reason || "the control connection closed"), { code: ev.code }));
    };
  }).finally(() => { opening = null; });
  return opening;
}

async function act(type) {
  const msg = { type };
  if (type === "disarm") {
    let state = null;
    try { state = (await api("/api/status")).state; } catch (err) { /* sent plain, below */ }
    const armed = state && state.heartbeat.armed;
    const alt = state && state.altitude.relative_alt_m;
    const flying = Boolean(armed && !(alt !== null && alt !== undefined && alt < AIRBORNE_M));
    if (flying) {
      if (!confirm("Disarm in flight? The motors stop and the vehicle falls.")) return;
      msg.force = true;
    }
  }
  for (let attempt = 0; attempt < 2; attempt++) {
    try {
      const ws = await open();
      ws.send(JSON.stringify(msg));
      toast(`${type}: sent`);
      clearTimeout(idleTimer);
      idleTimer = setTimeout(() => ws.close(), IDLE_CLOSE_MS);
      return;
    } catch (err) {
      if (err.code === CLOSE_UNAUTHORIZED && attempt === 0 && askToken()) continue;
      toast(`${type} not sent: ${err.message}`, { bad: true });
      return;
    }
  }
}

async function poll() {
  try {
    commandable = ["twin", "emergency"].includes((await api("/api/status")).control);
  } catch (err) {
    return; // unreachable: the buttons stay as they were
  }
  for (const g of groups) g.hidden = !commandable;
}

const home = $("toolbar") || $("replay-bar") || document.querySelector(".osd-menu");
if (home) home.append(emergencyButtons());
poll();
setInterval(poll, STATUS_MS);
