// fpv-station pilot page: the flight state table, the connection pill and LINK LOST.
//
// The telemetry comes from telemetry.js (the page's one WS /ws/telemetry?ack=1 feed; other
// modules listen to its window "fpv:telemetry" events). Freshness is honest: the pill says
// "live" only while messages actually arrive, and each row greys out and shows its age
// when its telemetry group is older than STALE_S. The page shows LINK LOST when the
// station says the autopilot is silent, when the station is unreachable, or when no state
// arrives at all.
import { $, el } from "/lib.js";
import { feed, groupAge } from "/telemetry.js";

const STALE_MS = 3000; // no message for this long while the socket is open: link lost
// Row (value element id) -> the telemetry groups it is drawn from, and its stale age.
const ROWS = {
  "v-ground-speed": [["vfr_hud", "global_position", "gps"], 2],
  "v-climb": [["vfr_hud", "global_position"], 2],
  "v-rel-alt": [["altitude"], 2],
  "v-armed": [["heartbeat"], 3],
  "v-mode": [["heartbeat"], 3],
  "v-gps": [["gps"], 2],
  "v-battery": [["battery"], 5],
  "v-heading": [["global_position", "vfr_hud"], 2],
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
const first = (...vals) => vals.find((v) => v !== null && v !== undefined) ?? null;

function draw() {
  const msg = pending;
  pending = null;
  if (!msg) return;
  const s = msg.state;
  const gp = s.global_position;
  const groundSpeed = first(
    s.vfr_hud.ground_speed_mps,
    gp.vx_mps !== null ? Math.hypot(gp.vx_mps, gp.vy_mps) : null,
    s.gps.ground_speed_mps,
  );
  const climb = first(s.vfr_hud.climb_mps, gp.vz_mps !== null ? -gp.vz_mps : null);
  $("v-ground-speed").textContent = num(groundSpeed);
  $("v-climb").textContent = num(climb);
  $("v-rel-alt").textContent = num(s.altitude.relative_alt_m);
  $("v-rel-alt-ref").textContent = {
    arming: "from arming",
    arming_retaken: `from arming (re-taken: ${s.altitude.retaken_because})`,
    first_fix: "from first GPS fix (not armed yet)",
    first_fix_retaken: `from first GPS fix (re-taken: ${s.altitude.retaken_because})`,
    none: "no reference yet",
  }[s.altitude.reference];
  const armed = $("v-armed");
  armed.textContent = s.heartbeat.t_mono === null ? "--" : s.heartbeat.armed ? "ARMED" : "disarmed";
  armed.className = s.heartbeat.armed ? "armed" : "disarmed";
  $("v-mode").textContent = s.heartbeat.t_mono === null ? "--" : s.heartbeat.mode;
  const fixNames = ["no GPS", "no fix", "2D", "3D", "DGPS", "RTK float", "RTK fixed"];
  $("v-gps").textContent = s.gps.t_mono === null
    ? "--"
    : `${fixNames[s.gps.fix_type] ?? "fix " + s.gps.fix_type}, ${s.gps.satellites ?? "?"} sats`;
  const b = s.battery;
  $("v-battery").textContent = b.t_mono === null
    ? "--"
    : `${num(b.voltage_v, 2)} V` + (b.remaining_pct !== null ? ` ${num(b.remaining_pct, 0)}%` : "");
  $("v-heading").textContent = num(first(gp.heading_deg, s.vfr_hud.heading_deg), 0);
  updateBanner();
}

function updateFreshness() {
  for (const [id, [groups, limit]] of Object.entries(ROWS)) {
    const ages = groups.map(groupAge).filter((a) => a !== null);
    const age = ages.length ? Math.min(...ages) : null;
    const stale = !feed.flowing() || age === null || age > limit;
    const { tr, age: ageEl } = rowAges[id];
    tr.classList.toggle("stale", stale);
    const text = stale && age !== null ? `${age.toFixed(0)} s old` : "";
    if (ageEl.textContent !== text) ageEl.textContent = text;
  }
  if (!feed.socketOpen) setConn("station unreachable", "bad");
  else if (feed.flowing()) setConn("live", "ok");
  else setConn(feed.latest ? "no telemetry" : "waiting for telemetry", "bad");
}

function updateBanner() {
  updateFreshness();
  const msg = feed.latest;
  const quietMs = performance.now() - (feed.receivedAt || openedAt);
  let detail = null;
  if (!feed.socketOpen) detail = "no connection to the station";
  else if (!msg) detail = quietMs > STALE_MS ? "no vehicle state" : null;
  else if (msg.state.link.link_lost) detail = "no heartbeat from the autopilot";
  else if (quietMs > STALE_MS) detail = "telemetry stopped";
  const banner = $("link-banner");
  banner.hidden = detail === null;
  $("link-banner-detail").textContent = detail ?? "";
  $("flight-state").classList.toggle("stale", detail !== null);
}

const openedAt = performance.now();
setInterval(updateBanner, 250);
