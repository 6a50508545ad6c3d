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
