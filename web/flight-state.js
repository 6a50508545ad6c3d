// fpv-station pilot page: live flight state from WS /ws/telemetry.
//
// Other page modules get the same telemetry without opening their own socket:
//   window.addEventListener("fpv:telemetry", (e) => use(e.detail));  // every message
//   window.fpv.latest                                                 // newest message
// A message is {t_server, t_server_mono, version, state: {heartbeat, gps, ..., link}}
// (names as companion/vehicle_state.py). The page shows LINK LOST when the station says
// the autopilot is silent, when the station itself is unreachable, or when no state
// arrives at all.
import { $, liveSocket } from "/lib.js";

const STALE_MS = 3000; // no message for this long while the socket is open: link lost
const fpv = (window.fpv = window.fpv || {});
fpv.latest = null;

let socketOpen = false;
let lastMessageAt = 0;
let pending = null; // newest message not drawn yet (draw at most once per frame)

liveSocket("/ws/telemetry", {
  open() {
    socketOpen = true;
    setConn("live", "ok");
    lastMessageAt = performance.now();
  },
  message(msg) {
    lastMessageAt = performance.now();
    fpv.latest = msg;
    window.dispatchEvent(new CustomEvent("fpv:telemetry", { detail: msg }));
    if (pending === null) requestAnimationFrame(draw);
    pending = msg;
  },
  close() {
    socketOpen = false;
    setConn("station unreachable", "bad");
  },
});

function setConn(text, cls) {
  const pill = $("conn-status");
  pill.textContent = text;
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

function updateBanner() {
  const msg = fpv.latest;
  let detail = null;
  if (!socketOpen) detail = "no connection to the station";
  else if (!msg) detail = performance.now() - lastMessageAt > STALE_MS ? "no vehicle state" : null;
  else if (msg.state.link.link_lost) detail = "no heartbeat from the autopilot";
  else if (performance.now() - lastMessageAt > STALE_MS) detail = "telemetry stopped";
  const banner = $("link-banner");
  banner.hidden = detail === null;
  $("link-banner-detail").textContent = detail ?? "";
  $("flight-state").classList.toggle("stale", detail !== null);
}

setInterval(updateBanner, 500);
