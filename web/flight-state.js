// fpv-station pilot page: the flight state table, the connection pill and LINK LOST.
//
// Drawn from the page's one telemetry feed (telemetry.js: `feed`, its readings, and its
// window "fpv:telemetry" event per message), at most once per animation frame. Freshness
// is honest: the pill says "live" only while messages actually arrive, and each row greys
// out and shows its age when the telemetry it is drawn from is older than its stale age
// (telemetry.js READINGS). The page shows LINK LOST when the station says the autopilot is
// silent, when the station is unreachable, or when no state arrives at all.
import { $, el } from "/lib.js";
import { FLOW_S, feed, fixName, reading } from "/telemetry.js";

// Row (value element id) -> the reading it shows (telemetry.js READINGS: its groups and
// stale age).
const ROWS = {
  "v-ground-speed": "groundSpeed",
  "v-climb": "climb",
  "v-rel-alt": "altitude",
  "v-armed": "heartbeat",
  "v-mode": "heartbeat",
  "v-gps": "gps",
  "v-battery": "battery",
  "v-heading": "heading",
};
const rowAges = {};
for (const id of Object.keys(ROWS)) {
  const tr = $(id).closest("tr");
  const age = el("small", { class: "age" });
  tr.querySelector("th").append(" ", age);
  rowAges[id] = { tr, age };
}

let pending = null; // newest message not drawn yet (draw at most once per frame)
window.addEventListener("fpv:telemetry", (e) => {
  if (pending === null) requestAnimationFrame(draw);
  pending = e.detail;
});

function setConn(text, cls) {
  const pill = $("conn-status");
  if (pill.textContent !== text) pill.textContent = text;
  pill.className = `pill ${cls}`;
}

const num = (v, digits = 1) => (v === null || v === undefined ? "--" : Number(v).toFixed(digits));

function draw() {
  const msg = pending;
  pending = null;
  if (!msg) return;
  $("v-ground-speed").textContent = num(reading("groundSpeed").value);
  $("v-climb").textContent = num(reading("climb").value);
  const alt = msg.state.altitude;
  $("v-rel-alt").textContent = num(alt.relative_alt_m);
  const by = alt.source === "relative_alt" ? ", by the autopilot's relative altitude" : "";
  const ref = {
    arming: "from arming",
    arming_retaken: `from arming (re-taken: ${alt.retaken_because})`,
    first_fix: "from first GPS fix (not armed yet)",
    first_fix_retaken: `from first GPS fix (re-taken: ${alt.retaken_because})`,
    none: "no reference yet",
  }[alt.reference];
  const refNote = $("v-rel-alt-ref");
  refNote.textContent = refNote.title = ref === undefined ? "" : ref + by;
  const hb = reading("heartbeat").value;
  const armed = $("v-armed");
  armed.textContent = hb === null ? "--" : hb.armed ? "ARMED" : "disarmed";
  armed.className = hb !== null && hb.armed ? "armed" : "disarmed";
  $("v-mode").textContent = hb === null ? "--" : hb.mode;
  const gps = reading("gps").value;
  $("v-gps").textContent = gps === null ? "--" : `${fixName(gps.fix_type)}, ${gps.satellites ?? "?"} sats`;
  const b = reading("battery").value;
  $("v-battery").textContent = b === null
    ? "--"
    : `${num(b.voltage_v, 2)} V` + (b.remaining_pct !== null ? ` ${num(b.remaining_pct, 0)}%` : "");
  $("v-heading").textContent = num(reading("heading").value, 0);
  updateBanner();
}

function updateFreshness() {
  for (const [id, name] of Object.entries(ROWS)) {
    const { age, stale } = reading(name);
    const { tr, age: ageEl } = rowAges[id];
    tr.classList.toggle("stale", stale);
    const text = stale && age !== null ? `${age.toFixed(0)} s old` : "";
    if (ageEl.textContent !== text) ageEl.textContent = text;
  }
  if (!feed.socketOpen) setConn("station unreachable", "bad");
  else if (feed.flowing()) setConn("live", "ok");
  else setConn(feed.latest ? "no telemetry" : "waiting for telemetry", "bad");
}

// LINK LOST, and why. No message for FLOW_S (telemetry.js) while the socket is open is a
// lost link: source seconds (a replay's log time), or wall seconds before the first
// message; the pill's "no telemetry" and the OSD's LINK LOST use the same threshold, so
// the three agree.
function updateBanner() {
  updateFreshness();
  const msg = feed.latest;
  const quietS = msg ? feed.sourceSince() : (performance.now() - openedAt) / 1000;
  let detail = null;
  if (!feed.socketOpen) detail = "no connection to the station";
  else if (!msg) detail = quietS > FLOW_S ? "no vehicle state" : null;
  else if (feed.ended) detail = "the replay has ended";
  else if (msg.state.link.link_lost) detail = "no heartbeat from the autopilot";
  else if (quietS > FLOW_S) detail = "telemetry stopped";
  const banner = $("link-banner");
  banner.hidden = detail === null;
  $("link-banner-detail").textContent = detail ?? "";
  $("flight-state").classList.toggle("stale", detail !== null);
}

const openedAt = performance.now();
setInterval(updateBanner, 250);
