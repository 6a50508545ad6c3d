// fpv-station: the one telemetry feed of a page (pilot and goggles), with its freshness.
//
//   import { feed, groupAge } from "/telemetry.js";
//   window.addEventListener("fpv:telemetry", (e) => use(e.detail));  // every message
//   window.addEventListener("fpv:status", (e) => use(e.detail));     // GET /api/status
//   feed.latest         newest message {t_server, t_server_mono, version, state: {...}}
//   feed.receivedAt     performance.now() when it arrived (0 before the first)
//   feed.socketOpen     the WebSocket to the station is open
//   feed.status         newest GET /api/status reply (polled every STATUS_MS), or null
//   feed.rate           the source's seconds per wall second, as the messages show it
//   feed.ended          the source has ended (a replay past its last record)
//   feed.sourceSince()  source seconds since the newest message, as the browser sees it now
//   feed.sourceSeconds(ms)  `ms` of wall time in the source's seconds
//   feed.flowing()      a message came within FLOW_S of the source's time (an open
//                       socket is not enough), and the source has not ended
//   groupAge(name)      source seconds since the vehicle's newest `state[name]`, as the
//                       browser sees it now (its age at sending + sourceSince()); null
//                       when the group was never heard
//   reading(name)       {value, age, stale} of one of READINGS (what the pilot page's table
//                       and the OSD show): the value and its age come from one group
//   fixName(fixType)    the name of a GPS fix type (the gps group's fix_type), e.g. "3D"
//
// One socket per page (ES modules load once): WS /ws/telemetry?ack=2, acknowledged after
// every second message is handled (the station keeps at most ACK_WINDOW messages
// unacknowledged, server/routes/telemetry.py), so a slow browser gets the newest state,
// never a backlog, and the station reads half as many acks as one per message.
//
// The source's clock. Messages carry the source's time (server/telemetry_json.py): the
// station's for a live vehicle, the log's for a replay, which runs at its ?speed= (x0.25,
// x4, as fast as it goes) and stops at the log's end. What the pages show between
// messages (ages, staleness, the flight timer, LINK LOST) runs on that clock, so that a
// replay shows what the pilot saw at that moment of the log at any speed: a value fresh in
// the log is fresh on a x0.25 replay, one stale in the log is stale at x4. Between
// messages the source's time is extrapolated at the rate the messages show (source
// seconds over wall seconds, over the last seconds of messages): 1 for a live vehicle,
// and for a replay its speed (the log's clock runs on through a silence in the
// log at that speed, companion/link.py). Once the station says the replay has ended
// (GET /api/status, link.replay_done) the log's time stands still and so does every age:
// the page holds the log's last moment (until the next status poll tells it, ages run on
// at the replay's rate).
import { expose } from "/debug.js";
import { api, liveSocket } from "/lib.js";

export const FLOW_S = 2; // no message for this long (source seconds): telemetry is not flowing
const STATUS_MS = 2000; // GET /api/status this often (link health, whether a replay ended)
// The rate is measured over messages at least RATE_MIN_MS apart, and at most RATE_SAMPLES
// of them back (about RATE_MIN_MS * RATE_SAMPLES of wall time).
const RATE_MIN_MS = 500;
const RATE_SAMPLES = 4;
// A measured rate this close to 1 is the station's clock seen through network jitter.
const RATE_SNAP = 0.1;
// Faster than this (a replay at ?speed=max) ages are extrapolated at this rate: a few
// milliseconds of wall time are seconds of the log there, and the states of those seconds
// exist but have not been sent yet (a few messages in flight at most), so they are not ages.
const RATE_MAX = 8;
// At most this many messages unacknowledged (two: 40 ms of states at 50 a second, what a
// busy browser can fall behind); the ack goes when the window is full, and reaches the
// station before its next tick on any usable network, so the rate does not drop.
const ACK_WINDOW = 2;

const samples = []; // [performance.now(), t_server_mono] of past messages, oldest first

export const feed = {
  latest: null,
  receivedAt: 0,
  socketOpen: false,
  status: null,
  rate: 1,
  ended: false,
  sourceSeconds(ms) {
    return this.ended ? 0 : (Math.min(this.rate, RATE_MAX) * ms) / 1000;
  },
  sourceSince() {
    return this.latest === null ? 0 : this.sourceSeconds(performance.now() - this.receivedAt);
  },
  flowing() {
    return this.socketOpen && this.latest !== null && !this.ended && this.sourceSince() < FLOW_S;
  },
};
expose("feed", feed);

// The source seconds per wall second over the last messages; a source whose time went
// back (the station restarted on another log) starts a new measure.
function measureRate(now, t) {
  const last = samples[samples.length - 1];
  if (last && t < last[1]) samples.length = 0;
  const first = samples[0];
  if (first && now - first[0] >= RATE_MIN_MS) {
    const rate = (t - first[1]) / ((now - first[0]) / 1000);
    feed.rate = Math.abs(rate - 1) <= RATE_SNAP ? 1 : rate;
  }
  if (!samples.length || now - samples[samples.length - 1][0] >= RATE_MIN_MS) {
    samples.push([now, t]);
    if (samples.length > RATE_SAMPLES) samples.shift();
  }
}

let unacked = 0; // messages handled since the last ack
const socket = liveSocket(`/ws/telemetry?ack=${ACK_WINDOW}`, {
  open() {
    feed.socketOpen = true;
    unacked = 0;
    samples.length = 0; // a new connection: perhaps a restarted station on another source
  },
  message(msg) {
    const now = performance.now();
    measureRate(now, msg.t_server_mono);
    feed.latest = msg;
    feed.receivedAt = now;
    window.dispatchEvent(new CustomEvent("fpv:telemetry", { detail: msg }));
    if (++unacked >= ACK_WINDOW) {
      socket.send({ ack: msg.version }); // acknowledges every message up to this one
      unacked = 0;
    }
  },
  close() { feed.socketOpen = false; },
});

async function pollStatus() {
  try {
    feed.status = await api("/api/status");
  } catch (err) {
    feed.status = null;
  }
  const link = feed.status && feed.status.link;
  feed.ended = Boolean(link && link.replay_done);
  window.dispatchEvent(new CustomEvent("fpv:status", { detail: feed.status }));
}
pollStatus();
setInterval(pollStatus, STATUS_MS);

export function groupAge(name) {
  const msg = feed.latest;
  if (!msg) return null;
  const g = msg.state[name];
  if (!g || g.t_mono === null || g.t_mono === undefined) return null;
  return Math.max(0, msg.t_server_mono - g.t_mono) + feed.sourceSince();
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

// GPS_RAW_INT's fix types by number, one name each for the table and the OSD.
const FIX_NAMES = ["no GPS", "no fix", "2D", "3D", "DGPS", "RTK float", "RTK fixed"];
export const fixName = (fixType) => FIX_NAMES[fixType] ?? `fix ${fixType}`;

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
