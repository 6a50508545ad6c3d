// fpv-station: the FPV on-screen display over the front camera (pilot and goggles pages).
//
//   <section id="front-view" data-osd-view> ... <script type="module" src="/osd.js">
//   import { mountOsd, pageOsd } from "/osd.js";
// osd.js mounts the page's OSD on that element when loaded: `pageOsd` (null on a page
// without one); mountOsd(view) mounts another (the goggles' right eye). An OSD's handle:
//   stats                the cost of each frame: {frames, totalMs, maxMs, recent} (ms;
//                        benchmarks/osd_frame_cost.py; with stats.raster set, the canvases
//                        are rasterized inside the timing, as the display would)
//   toggleMenu()         open or close the elements menu (every OSD of the page at once)
//   menuBox              the menu, where a page adds its own controls (emergency buttons)
//   setRunning(on)       stop drawing (a hidden view) or start again
//   setLine(name, text)  a page's own OSD line, data-osd=<name> (the goggles' task step)
//
// Drawn in the browser, once per animation frame (the display's rate, so at least the
// video's), from the page's one telemetry feed (telemetry.js: WS /ws/telemetry?ack=2, so
// what it shows is never a backlog) and its cameras (video.js). The horizon and the heading
// tape are canvases (osd-canvas.js); every other element is text, outlined so that it
// reads over sky and grass. Every element carries data-osd="<name>" and its text is the
// value shown (tests read them; the two canvases carry theirs as fallback text and data-
// attributes). A value whose telemetry group is older than its threshold greys out and
// shows its age. Elements can be switched off in a menu ("OSD" button, or the O key on the
// goggles); the choice is kept in localStorage.
//
// Each part of the OSD is one function below, called every frame with the frame's `f`
// ({msg, s: the vehicle state, dpr, optics, dirty, cam, vAge}): horizonLadder, headingTape,
// flightValues, vehicleStatus, homeItem, linkAndAges, messagesAndWarnings; the front
// camera's latency is a line of its own (latencyLine), the menu is elementsMenu.
import { expose } from "/debug.js";
import { el } from "/lib.js";
import { canvasResized, drawHorizon, drawTape, pictureOptics } from "/osd-canvas.js";
import { feed, fixName, groupAge, reading } from "/telemetry.js";
import { cameras } from "/video.js";

const HIDDEN_KEY = "fpv.osd.hidden";
const LOW_BATTERY_PCT = 20;
const MESSAGE_SHOWN_S = 10; // a vehicle message stays on the messages line this long
// Lines of messages shown, newest last: a refusal (COMMAND_ACK) and the vehicle's reason
// (its STATUSTEXT) arrive together, in either order.
const MESSAGE_LINES = 2;
const WARNING_SHOWN_S = 15; // an emergency/crash/failsafe message keeps its warning this long
const VIDEO_STALE_S = 1.0;
const REFUSED_SHOWN_S = 10; // "MAVLINK REFUSED" stays this long after the station last refused some
const SEVERITY = ["EMERG", "ALERT", "CRIT", "ERR", "WARN", "NOTE", "INFO", "DEBUG"];
const M_PER_DEG_LAT = 111_320;
const HOME_DOT_M = 1.0; // nearer home than this: a dot, not an arrow pointing at noise
const PAGES = [["/", "Pilot view"], ["/goggles.html", "Goggles"], ["/sessions.html", "Sessions"],
  ["/analysis.html", "Analysis"]];

// name -> the reading it shows (telemetry.js READINGS: its groups, when it is stale)
const ELEMENTS = {
  horizon: "attitude",
  heading: "heading",
  altitude: "altitude",
  climb: "climb",
  speed: "groundSpeed",
  battery: "battery",
  gps: "gps",
  mode: "heartbeat",
  armed: "heartbeat",
  timer: null,
  recording: null,
  home: "position",
  link: null,
  age: null,
  warning: null,
  messages: null,
};
export const OSD_ELEMENTS = Object.keys(ELEMENTS);

const fixed = (v, d = 1) => (v === null || v === undefined ? "--" : Number(v).toFixed(d));
const setText = (node, text) => { if (node.textContent !== text) node.textContent = text; };

// An element's value: `r` is its reading (its value is what `text` says), which greys the
// element out and adds its age when stale. `textNode`: where the text goes, when not the
// element itself (home's, beside its arrow).
function setValue(node, r, text, extraClass = "", textNode = node) {
  const { age, stale } = r;
  setText(textNode, stale && age !== null ? `${text} (${age.toFixed(0)}s)` : text);
  const cls = `osd-item osd-${node.dataset.osd}${stale ? " osd-stale" : ""}${extraClass ? " " + extraClass : ""}`;
  if (node.className !== cls) node.className = cls;
}

export function mountOsd(view, { menu = true } = {}) {
  const stats = { frames: 0, totalMs: 0, maxMs: 0, recent: [] };
  const root = el("div", { class: "osd", "aria-label": "on-screen display" });
  const nodes = elementNodes(root);
  const lines = el("div", { class: "osd-lines" }); // the latency and a page's own lines
  root.append(lines);
  view.append(root);
  const setLine = (name, text) => {
    let node = lines.querySelector(`[data-osd="${name}"]`);
    if (!node) {
      node = el("div", { class: "osd-item", "data-osd": name });
      // The latency first, the page's lines after it: both eyes of stereo in one order.
      if (name === "latency") lines.prepend(node); else lines.append(node);
    }
    setText(node, text);
  };
  const parts = [horizonLadder(nodes.horizon), headingTape(nodes.heading), flightValues(nodes),
    vehicleStatus(nodes), homeItem(nodes.home), linkAndAges(nodes), messagesAndWarnings(nodes)];
  const geometry = pictureGeometry(view, nodes.horizon, nodes.heading);
  // `dirty`: the canvases are redrawn even if their values did not change (a resize, an
  // element switched back on, a paused OSD running again).
  let dirty = true;
  const menuBox = elementsMenu(root, nodes, menu, () => { dirty = true; });

  function draw() {
    const { dpr, optics, changed, reach } = geometry();
    if (changed) dirty = true;
    latencyLine(setLine);
    const msg = feed.latest;
    if (!msg) { setText(nodes.warning, feed.socketOpen ? "NO TELEMETRY" : "STATION UNREACHABLE"); return; }
    const cam = cameras.latest.front;
    const f = { msg, s: msg.state, dpr, optics, reach, dirty, cam, vAge: videoAge(cam) };
    for (const part of parts) part(f);
    dirty = false;
  }

  // A paused OSD (the right eye with stereo off) asks for no frames at all: `raf` is the
  // frame asked for (0 while paused), so pausing cancels it and a second start is no
  // second loop.
  let raf = 0;
  function frame() {
    raf = requestAnimationFrame(frame);
    const t0 = performance.now();
    draw();
    if (stats.raster) { // benchmark only: the canvases' pixels made now, inside the timing
      for (const c of [nodes.horizon, nodes.heading]) c.getContext("2d").getImageData(0, 0, 1, 1);
    }
    const ms = performance.now() - t0;
    stats.frames += 1;
    stats.totalMs += ms;
    stats.maxMs = Math.max(stats.maxMs, ms);
    stats.recent.push(ms);
    if (stats.recent.length > (stats.keep || 600)) stats.recent.shift();
  }
  raf = requestAnimationFrame(frame);
  return {
    stats,
    toggleMenu() { setMenuOpen(!menuOpen); },
    menuBox,
    setRunning(on) {
      if (on === (raf !== 0)) return;
      cancelAnimationFrame(raf);
      raf = on ? requestAnimationFrame(frame) : 0;
      dirty = true;
    },
    setLine,
  };
}

// The elements, in the order they sit in the view: the two canvases, then text.
function elementNodes(root) {
  const horizon = el("canvas", { class: "osd-horizon", "data-osd": "horizon" });
  const heading = el("canvas", { class: "osd-heading", "data-osd": "heading" });
  const nodes = { horizon, heading };
  root.append(horizon, heading);
  for (const name of OSD_ELEMENTS) {
    if (nodes[name]) continue;
    nodes[name] = el("div", { class: `osd-item osd-${name}`, "data-osd": name }, "");
    root.append(nodes[name]);
  }
  return nodes;
}

// The canvases' sizes and the picture's optics in the horizon canvas' pixels (focal length
// and where the nose is), each frame; `changed`: the canvases must be redrawn. Sizes are
// read only after a resize or a zoom: reading them every frame forces a layout whenever
// anything on the page changed since the last. The canvases are watched as well as the
// view: the menu switching one off or on resizes its box (to nothing and back), and the
// ladder's reach follows the tape.
function pictureGeometry(view, horizon, heading) {
  let resized = true, sizeDpr = 0;
  let fit = "contain", opticsKey = ""; // how the picture sits in the view: its object-fit
  let reach = 0; // how far from the centre the pitch ladder may go: to the heading tape's foot
  const observer = new ResizeObserver(() => { resized = true; });
  for (const node of [view, horizon, heading]) observer.observe(node);
  return () => {
    const dpr = window.devicePixelRatio || 1;
    let changed = false;
    if (resized || dpr !== sizeDpr) {
      resized = false;
      sizeDpr = dpr;
      for (const c of [horizon, heading]) {
        c.width = Math.round(c.clientWidth * dpr);
        c.height = Math.round(c.clientHeight * dpr);
        canvasResized(c);
      }
      const img = view.querySelector(".video-stream");
      fit = img ? getComputedStyle(img).objectFit : "contain";
      reach = horizon.height / 2 - (heading.offsetTop + heading.offsetHeight) * dpr;
      changed = true;
    }
    const optics = pictureOptics(cameras.latest.front, view.querySelector(".video-stream"), fit, horizon);
    if (optics.key !== opticsKey) { opticsKey = optics.key; changed = true; }
    return { dpr, optics, changed, reach };
  };
}

// The horizon and pitch ladder: redrawn when the attitude (to a tenth of a degree) or the
// picture changed; its values are the canvas' data- attributes and fallback text (data-
// reach: how far from the centre the ladder may go, in the canvas' pixels).
function horizonLadder(canvas) {
  let key = "";
  return ({ dpr, optics, reach, dirty }) => {
    const r = reading("attitude"), att = r.value;
    const roll = att === null || att.roll_rad === null ? null : (att.roll_rad * 180) / Math.PI;
    const pitch = att === null || att.pitch_rad === null ? null : (att.pitch_rad * 180) / Math.PI;
    const k = `${fixed(roll, 1)},${fixed(pitch, 1)}`;
    if (!hidden.has("horizon") && (k !== key || dirty)) {
      key = k;
      drawHorizon(canvas, roll, pitch, optics, dpr, reach);
      canvas.dataset.roll = fixed(roll, 1);
      canvas.dataset.pitch = fixed(pitch, 1);
      canvas.dataset.tilt = fixed(optics.tiltDeg, 1);
      canvas.dataset.vfov = fixed(optics.vfovDeg, 1);
      canvas.dataset.reach = fixed(reach, 0);
    }
    setValue(canvas, r, `roll ${fixed(roll, 0)}° pitch ${fixed(pitch, 0)}°`);
  };
}

// The heading tape: redrawn when the heading (to a degree) or the canvas changed.
function headingTape(canvas) {
  let key = "";
  return ({ dpr, dirty }) => {
    const r = reading("heading"), hdg = r.value;
    const k = fixed(hdg, 0);
    if (!hidden.has("heading") && (k !== key || dirty)) {
      key = k;
      drawTape(canvas, hdg, dpr);
      canvas.dataset.heading = k;
    }
    setValue(canvas, r, hdg === null ? "---" : String(Math.round(hdg) % 360).padStart(3, "0"));
  };
}

const lowBattery = (b) => b.remaining_pct !== null && b.remaining_pct < LOW_BATTERY_PCT;

// Altitude, climb, ground speed, battery and GPS.
function flightValues(nodes) {
  return ({ s }) => {
    const altR = reading("altitude");
    setValue(nodes.altitude, altR, `ALT ${fixed(altR.value && altR.value.relative_alt_m)} m`);
    const climbR = reading("climb"), climb = climbR.value;
    setValue(nodes.climb, climbR, `VS ${climb !== null && climb > 0 ? "+" : ""}${fixed(climb)} m/s`);
    const speedR = reading("groundSpeed");
    setValue(nodes.speed, speedR, `GS ${fixed(speedR.value)} m/s`);
    const b = s.battery;
    setValue(nodes.battery, reading("battery"),
      `${fixed(b.voltage_v, 1)} V ${fixed(b.remaining_pct, 0)}% ${fixed(b.consumed_mah, 0)} mAh`,
      lowBattery(b) ? "osd-bad" : "");
    const fix = s.gps.t_mono === null ? "NO GPS" : fixName(s.gps.fix_type).toUpperCase();
    setValue(nodes.gps, reading("gps"), `${fix} ${s.gps.satellites ?? "?"} sats`, s.gps.fix_type < 3 ? "osd-bad" : "");
  };
}

// Flight mode, armed, the flight timer and NOT RECORDING.
function vehicleStatus(nodes) {
  return ({ s }) => {
    const hb = s.heartbeat, hbR = reading("heartbeat");
    setValue(nodes.mode, hbR, hb.t_mono === null ? "--" : hb.mode);
    setValue(nodes.armed, hbR, hb.t_mono === null ? "--" : hb.armed ? "ARMED" : "DISARMED", hb.armed ? "osd-bad" : "");
    // The flight timer from the state (every page shows the same, one opened mid-flight
    // too): seconds armed as of the last HEARTBEAT, running on by the group's age while
    // armed, held after disarming (companion/vehicle_state.py Heartbeat).
    const armedFor = hb.armed_for_s ?? 0;
    const timerS = hb.armed ? armedFor + (groupAge("heartbeat") ?? 0) : armedFor;
    const mm = Math.floor(timerS / 60), ss = Math.floor(timerS % 60);
    setText(nodes.timer, `${String(mm).padStart(2, "0")}:${String(ss).padStart(2, "0")}`);
    // Armed and no session recording the flight (the station says so: a start refused and
    // being retried, a session cut short, recording off); disarming clears it at once.
    const unrecorded = hb.armed && station.notRecording;
    setText(nodes.recording, unrecorded ? "NOT RECORDING" : "");
    const recCls = `osd-item osd-recording${unrecorded ? " osd-bad" : ""}`;
    if (nodes.recording.className !== recCls) nodes.recording.className = recCls;
  };
}

// Home: distance and an arrow relative to the nose. The arrow is an SVG whose rotation is
// an attribute (scripts set no styles); within HOME_DOT_M of home the bearing is GPS noise,
// so a dot instead. The mark shown, "arrow", "dot" or "none" (no position or no home), is
// data-mark; only the arrow has a rotation and data-bearing (the two change together).
function homeItem(node) {
  const homeArrow = el("span", { class: "osd-home-arrow" });
  homeArrow.innerHTML = '<svg viewBox="-10 -10 20 20" width="1.1em" height="1.1em"><path d="M0 -9 L6 7 L0 3 L-6 7 Z" fill="currentColor" stroke="#000" stroke-width="1.5" visibility="hidden"/><circle r="3.5" fill="currentColor" stroke="#000" stroke-width="1.5" visibility="hidden"/></svg>';
  const [arrowPath, homeDot] = homeArrow.firstChild.children;
  const homeText = el("span", {}, "");
  node.append(homeArrow, homeText);
  // The elements change only when the mark does (this runs every frame).
  const showMark = (mark) => {
    if (node.dataset.mark === mark) return;
    node.dataset.mark = mark;
    arrowPath.setAttribute("visibility", mark === "arrow" ? "visible" : "hidden");
    homeDot.setAttribute("visibility", mark === "dot" ? "visible" : "hidden");
    if (mark === "arrow") return;
    arrowPath.removeAttribute("transform");
    delete node.dataset.bearing;
  };
  return ({ s }) => {
    const posR = reading("position"), pos = posR.value;
    const home = s.altitude;
    let text = "H --", mark = "none";
    if (pos !== null && home.home_lat_deg !== null && home.home_lat_deg !== undefined) {
      const north = (home.home_lat_deg - pos.lat_deg) * M_PER_DEG_LAT;
      const east = (home.home_lon_deg - pos.lon_deg) * M_PER_DEG_LAT * Math.cos((pos.lat_deg * Math.PI) / 180);
      const dist = Math.hypot(north, east);
      text = `H ${fixed(dist, 0)} m`;
      if (dist < HOME_DOT_M) mark = "dot";
      else {
        mark = "arrow";
        const bearing = ((Math.atan2(east, north) * 180) / Math.PI + 360) % 360;
        const rel = (((bearing - (reading("heading").value ?? 0)) % 360) + 360) % 360;
        const rot = `rotate(${rel.toFixed(0)})`;
        if (arrowPath.getAttribute("transform") !== rot) {
          arrowPath.setAttribute("transform", rot);
          node.dataset.bearing = rel.toFixed(0);
        }
      }
    }
    showMark(mark);
    setValue(node, posR, text, "", homeText);
  };
}

// The front camera's newest frame on screen, its age now (video.js: its age when drawn,
// and the time since). A NO SIGNAL card is no frame: then the camera's own figure from
// /api/cameras (none for a camera never seen).
function videoAge(cam) {
  const shown = cameras.frames.front;
  if (shown && shown.signal) return shown.ageAtDrawS + (performance.now() - shown.drawnAt) / 1000;
  if (!cam || cam.last_frame_age_s === null || cam.last_frame_age_s === undefined) return null;
  return cam.last_frame_age_s + (performance.now() - cameras.receivedAt) / 1000;
}

// Link: loss from /api/status (telemetry.js polls it), RSSI from RC_CHANNELS when the
// receiver has it. Ages: the newest vehicle telemetry and the front camera's frame.
function linkAndAges(nodes) {
  return ({ s, vAge }) => {
    const rssi = s.rc.rssi !== null && s.rc.rssi !== 255 ? ` RSSI ${Math.round((s.rc.rssi / 254) * 100)}%` : "";
    const loss = link.loss === null ? "" : `LQ ${fixed(100 * (1 - link.loss), 0)}%`;
    setText(nodes.link, `${loss}${rssi}`.trim() || "LQ --");
    const tAge = ageOfNewest();
    setText(nodes.age, `TLM ${tAge === null ? "--" : tAge.toFixed(1) + "s"} VID ${vAge === null ? "--" : vAge.toFixed(1) + "s"}`);
  };
}

// The messages line and the centre warnings (how long each shows: in the source's time).
function messagesAndWarnings(nodes) {
  return ({ msg, s, cam, vAge }) => {
    const now = msg.t_server_mono + feed.sourceSince();
    const recent = s.messages.recent.filter((m) => now - m.t_mono < MESSAGE_SHOWN_S);
    setText(nodes.messages, recent.slice(-MESSAGE_LINES)
      .map((m) => `${SEVERITY[m.severity] ?? "MSG"} ${m.text}`).join("\n"));
    const warnings = [];
    // Station down: every group ages, the GPS's too; only a vehicle heard can lose its GPS.
    const heard = feed.flowing() && !s.link.link_lost;
    if (!feed.socketOpen) warnings.push("STATION UNREACHABLE");
    else if (!heard) warnings.push("LINK LOST");
    if (lowBattery(s.battery)) warnings.push("LOW BATTERY");
    if (heard && s.gps.t_mono !== null && (s.gps.fix_type < 3 || (groupAge("gps") ?? 0) > 3)) {
      warnings.push("GPS LOST");
    }
    const serious = s.messages.recent.filter((m) => m.kind === "statustext" && now - m.t_mono < WARNING_SHOWN_S);
    if (serious.some((m) => /fail-?safe/i.test(m.text)) || /failsafe/i.test(s.heartbeat.mode)) warnings.push("FAILSAFE");
    if (serious.some((m) => /crash/i.test(m.text))) warnings.push("CRASH");
    else if (serious.some((m) => m.severity <= 2)) warnings.push("EMERGENCY");
    if (cam && (!cam.signal || (vAge !== null && vAge > VIDEO_STALE_S))) warnings.push("VIDEO STALE");
    if (link.refusedAt !== null && performance.now() - link.refusedAt < REFUSED_SHOWN_S * 1000) {
      warnings.push("MAVLINK REFUSED");
    }
    setText(nodes.warning, warnings.join(" · "));
  };
}

// The front camera's latency to the screen, p50/p99 over video.js's window: R2S for the
// twin's stamped frames, C2S for others' capture time; empty while there are no figures.
function latencyLine(setLine) {
  const lat = cameras.latency.front;
  setLine("latency", lat ? `${lat.kind === "render" ? "R2S" : "C2S"} ${lat.p50.toFixed(0)}/${lat.p99.toFixed(0)}ms` : "");
}

// The elements menu: a box per element (the page's one choice, `hidden`), links to the
// other pages (the goggles page has no other chrome to hold them) and the "OSD" button.
// `redraw`: called when the choice changed. Returns the menu's box.
function elementsMenu(root, nodes, withButton, redraw) {
  const menuBox = el("div", { class: "osd-menu", hidden: true, "aria-label": "OSD elements" });
  const boxes = {};
  for (const name of OSD_ELEMENTS) {
    const box = (boxes[name] = el("input", { type: "checkbox", "data-osd-toggle": name }));
    box.addEventListener("change", () => setHidden(name, !box.checked));
    menuBox.append(el("label", {}, box, ` ${name}`));
  }
  const nav = el("nav", { class: "osd-nav", "aria-label": "pages" });
  for (const [href, name] of PAGES) {
    if (href !== location.pathname) nav.append(el("a", { href }, name));
  }
  menuBox.append(nav);
  const menuButton = el("button", { type: "button", class: "osd-menu-button", title: "OSD elements (O)" }, "OSD");
  menuButton.addEventListener("click", () => setMenuOpen(!menuOpen));
  if (withButton) root.append(menuButton);
  root.append(menuBox);
  menus.push((open) => { menuBox.hidden = !open; });
  menuBox.hidden = !menuOpen;
  const applyHidden = () => {
    for (const name of OSD_ELEMENTS) {
      nodes[name].hidden = hidden.has(name);
      boxes[name].checked = !hidden.has(name);
    }
    redraw();
  };
  mounted.push(applyHidden);
  applyHidden();
  return menuBox;
}

// Which elements are switched off: one choice for every OSD of the page (both eyes of
// stereo), kept in localStorage. `mounted`: each OSD's applyHidden.
const hidden = new Set();
try { for (const name of JSON.parse(localStorage.getItem(HIDDEN_KEY) || "[]")) hidden.add(name); } catch (err) { /* none */ }
const mounted = [];
// Whether the menu is open: one state for every OSD of the page, so that in stereo both
// eyes show it (one menu seen by one eye only does not fuse). `menus`: each OSD's.
let menuOpen = false;
const menus = [];
function setMenuOpen(open) {
  menuOpen = open;
  for (const apply of menus) apply(open);
}
function setHidden(name, off) {
  if (off) hidden.add(name); else hidden.delete(name);
  localStorage.setItem(HIDDEN_KEY, JSON.stringify([...hidden]));
  for (const apply of mounted) apply();
}

// The link's packet loss, from the page's one GET /api/status (telemetry.js polls it; it
// is not part of the vehicle state). Also whether the station is refusing MAVLink (datagrams
// from hosts other than the link's peer, packets failing signing): someone may be
// injecting; `refusedAt` is when the count last grew.
const link = { loss: null, refusedTotal: null, refusedAt: null };
// Whether the vehicle is armed and no session records it (GET /api/status, recording).
const station = { notRecording: false };
window.addEventListener("fpv:status", (e) => {
  const st = e.detail;
  station.notRecording = Boolean(st && st.recording && st.recording.not_recording);
  link.loss = st && st.link ? st.link.loss_ratio : null;
  const sec = st && st.link && st.link.security;
  if (sec) {
    // signing's one figure (LinkSecurity.refused), and datagrams from other hosts
    const total = sec.refused + sec.foreign_datagrams + sec.forward_foreign_datagrams;
    if (link.refusedTotal !== null && total > link.refusedTotal) link.refusedAt = performance.now();
    link.refusedTotal = total;
  }
});

// Seconds since the vehicle was last heard (source seconds, as the browser sees it now).
function ageOfNewest() {
  let newest = null;
  for (const g of ["heartbeat", "gps", "global_position", "vfr_hud", "attitude", "battery"]) {
    const age = groupAge(g);
    if (age !== null && (newest === null || age < newest)) newest = age;
  }
  return newest;
}

const view = document.querySelector("[data-osd-view]");
export const pageOsd = view ? mountOsd(view) : null;
if (pageOsd) expose("osd", pageOsd);
