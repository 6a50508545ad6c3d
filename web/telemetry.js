// fpv-station: the one telemetry feed of a page (pilot and goggles), with its freshness.
//
//   import { feed, groupAge } from "/telemetry.js";
//   window.addEventListener("fpv:telemetry", (e) => use(e.detail));  // every message
//   feed.latest         newest message {t_server, t_server_mono, version, state: {...}}
//   feed.receivedAt     performance.now() when it arrived (0 before the first)
//   feed.socketOpen     the WebSocket to the station is open
//   feed.flowing()      a message arrived within FLOW_MS (a socket open is not enough)
//   groupAge(name)      seconds since the vehicle's newest `state[name]`, as the browser
//                       sees it now (station-clock age at sending + time since arrival);
//                       null when the group was never heard
//   reading(name)       {value, age, stale} of one of READINGS (what the pilot page's table
//                       and the OSD show): the value and its age come from one group
//
// One socket per page (ES modules load once): WS /ws/telemetry?ack=1, acknowledged after
// each message is handled, so a slow browser gets the newest state, never a backlog.
import { liveSocket } from "/lib.js";

export const FLOW_MS = 2000; // no message for this long: telemetry is not flowing
const fpv = (window.fpv = window.fpv || {});

export const feed = {
  latest: null,
  receivedAt: 0,
  socketOpen: false,
  flowing() {
    return this.socketOpen && this.latest !== null && performance.now() - this.receivedAt < FLOW_MS;
  },
};
fpv.latest = null;

const socket = liveSocket("/ws/telemetry?ack=1", {
  open() { feed.socketOpen = true; },
  message(msg) {
    feed.latest = fpv.latest = msg;
    feed.receivedAt = performance.now();
    window.dispatchEvent(new CustomEvent("fpv:telemetry", { detail: msg }));
    socket.send({ ack: msg.version });
  },
  close() { feed.socketOpen = false; },
});

export function groupAge(name) {
  const msg = feed.latest;
  if (!msg) return null;
  const g = msg.state[name];
  if (!g || g.t_mono === null || g.t_mono === undefined) return null;
  return Math.max(0, msg.t_server_mono - g.t_mono) + (performance.now() - feed.receivedAt) / 1000;
}

// What the pages show, each from the first of its groups that has it, and stale after
// `staleS`. A value and its age come from the same group, and a fresh group is preferred
// to a quiet one: when VFR_HUD stops (another GCS set its stream rate to 0) while
// GLOBAL_POSITION_INT goes on, the speed is the position's, not VFR_HUD's last one
// passed off as fresh by the position's age.
const deg = (rad) => ((((rad * 180) / Math.PI) % 360) + 360) % 360;
export const READINGS = {
  groundSpeed: [2, [["vfr_hud", (g) => g.ground_speed_mps],
    ["global_position", (g) => (g.vx_mps === null ? null : Math.hypot(g.vx_mps, g.vy_mps))],
    ["gps", (g) => g.ground_speed_mps]]],
  climb: [2, [["vfr_hud", (g) => g.climb_mps],
    ["global_position", (g) => (g.vz_mps === null ? null : -g.vz_mps)]]],
  heading: [2, [["global_position", (g) => g.heading_deg], ["vfr_hud", (g) => g.heading_deg],
    ["attitude", (g) => (g.yaw_rad === null ? null : deg(g.yaw_rad))]]],
  position: [2, [["global_position", (g) => (g.lat_deg === null ? null : g)],
    ["gps", (g) => (g.lat_deg === null ? null : g)]]], // {lat_deg, lon_deg}
  // Whole groups: the value is the group itself, once it was heard.
  attitude: [1, [["attitude", (g) => g]]],
  altitude: [2, [["altitude", (g) => g]]],
  heartbeat: [3, [["heartbeat", (g) => g]]],
  gps: [2, [["gps", (g) => g]]],
  battery: [5, [["battery", (g) => g]]],
};

export function reading(name) {
  const [staleS, sources] = READINGS[name];
  const s = feed.latest ? feed.latest.state : null;
  let quiet = null; // the first value found, while no fresh one is
  for (const [group, get] of s ? sources : []) {
    const age = groupAge(group);
    const value = age === null ? null : get(s[group]);
    if (value === null || value === undefined) continue;
    if (age <= staleS && feed.flowing()) return { value, age, stale: false };
    quiet ??= { value, age, stale: true };
  }
  return quiet ?? { value: null, age: null, stale: true };
}
