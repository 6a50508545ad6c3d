// fpv-station: the FPV on-screen display over the front camera (pilot and goggles pages).
//
//   <section id="front-view" data-osd-view> ... <script type="module" src="/osd.js">
// mounts the OSD on that element when loaded; window.fpv.osd is then
// {stats, toggleMenu(), setRunning(on), setLine(name, text)} (a page's own OSD lines, e.g.
// the goggles' task step).
//
// Drawn in the browser, once per animation frame (the display's rate, so at least the
// video's), from the page's one telemetry feed (telemetry.js: WS /ws/telemetry?ack=2, so
// what it shows is never a backlog). The horizon and the heading tape are canvases; every
// other element is text, outlined so that it reads over sky and grass. Every element
// carries data-osd="<name>" and its text is the value shown (tests read them; the two
// canvases carry theirs as fallback text and data- attributes). A value whose telemetry
// group is older than its threshold greys out and shows its age. Elements can be switched
// off in a menu ("OSD" button, or the O key on the goggles); the choice is kept in
// localStorage. Cost per frame: window.fpv.osdStats (benchmarks/osd_frame_cost.py; with
// osdStats.raster set, the canvases are rasterized inside the timing, as the display would).
import { el } from "/lib.js";
import { feed, groupAge, reading } from "/telemetry.js";

const HIDDEN_KEY = "fpv.osd.hidden";
const LOW_BATTERY_PCT = 20;
const MESSAGE_SHOWN_S = 10; // a vehicle message stays on the messages line this long
// Lines of messages shown, newest last: a refusal (COMMAND_ACK) and the vehicle's reason
// (its STATUSTEXT) arrive together, in either order.
const MESSAGE_LINES = 2;
const WARNING_SHOWN_S = 15; // an emergency/crash/failsafe message keeps its warning this long
const VIDEO_STALE_S = 1.0;
const REFUSED_SHOWN_S = 10; // "MAVLINK REFUSED" stays this long after the station last refused some
// The camera's optics (its tilt above the nose and vertical field of view) come from its
// settings through GET /api/cameras (video.js: fpv.cameras); a camera that does not say is
// taken as looking along the nose with this field of view.
const DEFAULT_VFOV_DEG = 60;
const D2R = Math.PI / 180;
const FIX_NAMES = ["NO GPS", "NO FIX", "2D", "3D", "DGPS", "RTK FLT", "RTK FIX"];
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

export function mountOsd(view, { menu = true } = {}) {
  const fpv = (window.fpv = window.fpv || {});
  // The page's OSD (the first mounted) is fpv.osdStats; a second one (the goggles' right
  // eye) has its own, on its handle.
  const stats = { frames: 0, totalMs: 0, maxMs: 0, recent: [] };
  if (!fpv.osdStats) fpv.osdStats = stats;
  const root = el("div", { class: "osd", "aria-label": "on-screen display" });
  const horizon = el("canvas", { class: "osd-horizon", "data-osd": "horizon" });
  const heading = el("canvas", { class: "osd-heading", "data-osd": "heading" });
  const nodes = { horizon, heading };
  root.append(horizon, heading);
  for (const name of OSD_ELEMENTS) {
    if (nodes[name]) continue;
    nodes[name] = el("div", { class: `osd-item osd-${name}`, "data-osd": name }, "");
    root.append(nodes[name]);
  }
  // The arrow to home: an SVG whose rotation is an attribute (scripts set no styles).
  const homeArrow = el("span", { class: "osd-home-arrow" });
  // Within HOME_DOT_M of home the bearing is GPS noise: a dot instead of the arrow.
  homeArrow.innerHTML = '<svg viewBox="-10 -10 20 20" width="1.1em" height="1.1em"><path d="M0 -9 L6 7 L0 3 L-6 7 Z" fill="currentColor" stroke="#000" stroke-width="1.5" visibility="hidden"/><circle r="3.5" fill="currentColor" stroke="#000" stroke-width="1.5" visibility="hidden"/></svg>';
  const [arrowPath, homeDot] = homeArrow.firstChild.children;
  // The mark shown, "arrow", "dot" or "none" (no position or no home), is data-mark; the
  // elements change only when it does (this runs every frame). Only the arrow has a
  // rotation and data-bearing (the two change together, in draw()).
  const showHomeMark = (mark) => {
    if (nodes.home.dataset.mark === mark) return;
    nodes.home.dataset.mark = mark;
    arrowPath.setAttribute("visibility", mark === "arrow" ? "visible" : "hidden");
    homeDot.setAttribute("visibility", mark === "dot" ? "visible" : "hidden");
    if (mark === "arrow") return;
    arrowPath.removeAttribute("transform");
    delete nodes.home.dataset.bearing;
  };
  const homeText = el("span", {}, "");
  nodes.home.append(homeArrow, homeText);
  const lines = el("div", { class: "osd-lines" }); // extra lines a page adds (the task step)
  root.append(lines);
  view.append(root);

  // -- switching elements on and off (the page's one choice: `hidden`, below) ----------
  const menuBox = el("div", { class: "osd-menu", hidden: true, "aria-label": "OSD elements" });
  const boxes = {};
  for (const name of OSD_ELEMENTS) {
    const box = (boxes[name] = el("input", { type: "checkbox", "data-osd-toggle": name }));
    box.addEventListener("change", () => setHidden(name, !box.checked));
    menuBox.append(el("label", {}, box, ` ${name}`));
  }
  // The other pages, from the menu: the goggles page has no other chrome to hold them.
  const nav = el("nav", { class: "osd-nav", "aria-label": "pages" });
  for (const [href, name] of PAGES) {
    if (href !== location.pathname) nav.append(el("a", { href }, name));
  }
  menuBox.append(nav);
  const menuButton = el("button", { type: "button", class: "osd-menu-button", title: "OSD elements (O)" }, "OSD");
  menuButton.addEventListener("click", () => setMenuOpen(!menuOpen));
  if (menu) root.append(menuButton);
  root.append(menuBox);
  menus.push((open) => { menuBox.hidden = !open; });
  menuBox.hidden = !menuOpen;
  function applyHidden() {
    for (const name of OSD_ELEMENTS) {
      nodes[name].hidden = hidden.has(name);
      boxes[name].checked = !hidden.has(name);
    }
    dirty = true;
  }
  mounted.push(applyHidden);

  let attitudeKey = "", headingKey = "", dirty = true;
  let resized = true, sizeDpr = 0;
  // How the picture sits in the view: its canvas's object-fit, read after a resize.
  let fit = "contain", opticsKey = "";
  new ResizeObserver(() => { resized = true; }).observe(view);

  const setText = (node, text) => { if (node.textContent !== text) node.textContent = text; };
  // `r`: the element's reading (its value is what `text` says), which greys it out.
  function setValue(name, r, text, extraClass = "") {
    const { age, stale } = r;
    const node = name === "home" ? homeText : nodes[name];
    const shown = stale && age !== null ? `${text} (${age.toFixed(0)}s)` : text;
    setText(node, shown);
    const cls = `osd-item osd-${name}${stale ? " osd-stale" : ""}${extraClass ? " " + extraClass : ""}`;
    if (nodes[name].className !== cls) nodes[name].className = cls;
  }

  // -- one frame -----------------------------------------------------------------------
  // A paused OSD (the right eye with stereo off) asks for no frames at all: `raf` is the
  // frame asked for (0 while paused), so pausing cancels it and a second start is no
  // second loop.
  let raf = 0;
  function frame() {
    raf = requestAnimationFrame(frame);
    const t0 = performance.now();
    draw();
    if (stats.raster) { // benchmark only: the canvases' pixels made now, inside the timing
      for (const c of [horizon, heading]) c.getContext("2d").getImageData(0, 0, 1, 1);
    }
    const ms = performance.now() - t0;
    stats.frames += 1;
    stats.totalMs += ms;
    stats.maxMs = Math.max(stats.maxMs, ms);
    stats.recent.push(ms);
    if (stats.recent.length > (stats.keep || 600)) stats.recent.shift();
  }

  function draw() {
    const msg = feed.latest;
    const s = msg ? msg.state : null;
    // Sizes are read only after a resize (ResizeObserver below) or a zoom: reading them
    // every frame forces a layout whenever anything on the page changed since the last.
    const dpr = window.devicePixelRatio || 1;
    if (resized || dpr !== sizeDpr) {
      resized = false;
      sizeDpr = dpr;
      for (const c of [horizon, heading]) {
        c.width = Math.round(c.clientWidth * dpr);
        c.height = Math.round(c.clientHeight * dpr);
        canvasFont.delete(c); // a resized canvas has lost its drawing state
      }
      const img = view.querySelector(".video-stream");
      fit = img ? getComputedStyle(img).objectFit : "contain";
      dirty = true;
    }
    // The picture's optics, in the horizon canvas' pixels: focal length and where the nose is.
    const cam = (fpv.cameras || {}).front;
    const optics = pictureOptics(cam, view.querySelector(".video-stream"), fit, horizon);
    if (optics.key !== opticsKey) { opticsKey = optics.key; dirty = true; }
    if (!s) { setText(nodes.warning, feed.socketOpen ? "NO TELEMETRY" : "STATION UNREACHABLE"); return; }
    // Horizon and pitch ladder.
    const attR = reading("attitude"), att = attR.value;
    const roll = att === null || att.roll_rad === null ? null : (att.roll_rad * 180) / Math.PI;
    const pitch = att === null || att.pitch_rad === null ? null : (att.pitch_rad * 180) / Math.PI;
    const aKey = `${fixed(roll, 1)},${fixed(pitch, 1)}`;
    if (!hidden.has("horizon") && (aKey !== attitudeKey || dirty)) {
      attitudeKey = aKey;
      drawHorizon(horizon, roll, pitch, optics, dpr);
      horizon.dataset.roll = fixed(roll, 1);
      horizon.dataset.pitch = fixed(pitch, 1);
      horizon.dataset.tilt = fixed(optics.tiltDeg, 1);
      horizon.dataset.vfov = fixed(optics.vfovDeg, 1);
    }
    setValue("horizon", attR, `roll ${fixed(roll, 0)}° pitch ${fixed(pitch, 0)}°`);
    // Heading tape.
    const hdgR = reading("heading"), hdg = hdgR.value;
    const hKey = fixed(hdg, 0);
    if (!hidden.has("heading") && (hKey !== headingKey || dirty)) {
      headingKey = hKey;
      drawTape(heading, hdg, dpr);
      heading.dataset.heading = hKey;
    }
    setValue("heading", hdgR, hdg === null ? "---" : String(Math.round(hdg) % 360).padStart(3, "0"));
    dirty = false;

    const altR = reading("altitude");
    setValue("altitude", altR, `ALT ${fixed(altR.value && altR.value.relative_alt_m)} m`);
    const climbR = reading("climb"), climb = climbR.value;
    setValue("climb", climbR, `VS ${climb !== null && climb > 0 ? "+" : ""}${fixed(climb)} m/s`);
    const speedR = reading("groundSpeed");
    setValue("speed", speedR, `GS ${fixed(speedR.value)} m/s`);
    const b = s.battery;
    const low = b.remaining_pct !== null && b.remaining_pct < LOW_BATTERY_PCT;
    setValue("battery", reading("battery"),
      `${fixed(b.voltage_v, 1)} V ${fixed(b.remaining_pct, 0)}% ${fixed(b.consumed_mah, 0)} mAh`, low ? "osd-bad" : "");
    const fix = s.gps.t_mono === null ? "NO GPS" : FIX_NAMES[s.gps.fix_type] ?? `FIX ${s.gps.fix_type}`;
    setValue("gps", reading("gps"), `${fix} ${s.gps.satellites ?? "?"} sats`, s.gps.fix_type < 3 ? "osd-bad" : "");
    const hbR = reading("heartbeat");
    setValue("mode", hbR, s.heartbeat.t_mono === null ? "--" : s.heartbeat.mode);
    setValue("armed", hbR, s.heartbeat.t_mono === null ? "--" : s.heartbeat.armed ? "ARMED" : "DISARMED",
      s.heartbeat.armed ? "osd-bad" : "");
    // The flight timer from the state (every page shows the same, one opened mid-flight
    // too): seconds armed as of the last HEARTBEAT, running on by the group's age while
    // armed, held after disarming (companion/vehicle_state.py Heartbeat).
    const armedFor = s.heartbeat.armed_for_s ?? 0;
    const timerS = s.heartbeat.armed ? armedFor + (groupAge("heartbeat") ?? 0) : armedFor;
    const mm = Math.floor(timerS / 60), ss = Math.floor(timerS % 60);
    setText(nodes.timer, `${String(mm).padStart(2, "0")}:${String(ss).padStart(2, "0")}`);
    // Armed and no session recording the flight (the station says so: a start refused and
    // being retried, a session cut short, recording off); disarming clears it at once.
    const unrecorded = s.heartbeat.armed && station.notRecording;
    setText(nodes.recording, unrecorded ? "NOT RECORDING" : "");
    const recCls = `osd-item osd-recording${unrecorded ? " osd-bad" : ""}`;
    if (nodes.recording.className !== recCls) nodes.recording.className = recCls;

    // Home: distance and an arrow relative to the nose.
    const posR = reading("position"), pos = posR.value;
    const home = s.altitude;
    let homeTxt = "H --", mark = "none";
    if (pos !== null && home.home_lat_deg !== null && home.home_lat_deg !== undefined) {
      const north = (home.home_lat_deg - pos.lat_deg) * M_PER_DEG_LAT;
      const east = (home.home_lon_deg - pos.lon_deg) * M_PER_DEG_LAT * Math.cos((pos.lat_deg * Math.PI) / 180);
      const dist = Math.hypot(north, east);
      homeTxt = `H ${fixed(dist, 0)} m`;
      if (dist < HOME_DOT_M) mark = "dot";
      else {
        mark = "arrow";
        const bearing = ((Math.atan2(east, north) * 180) / Math.PI + 360) % 360;
        const rel = (((bearing - (hdg ?? 0)) % 360) + 360) % 360;
        const rot = `rotate(${rel.toFixed(0)})`;
        if (arrowPath.getAttribute("transform") !== rot) {
          arrowPath.setAttribute("transform", rot);
          nodes.home.dataset.bearing = rel.toFixed(0);
        }
      }
    }
    showHomeMark(mark);
    setValue("home", posR, homeTxt);

    // Link: loss from /api/status (telemetry.js polls it), RSSI from RC_CHANNELS when the receiver has it.
    const rssi = s.rc.rssi !== null && s.rc.rssi !== 255 ? ` RSSI ${Math.round((s.rc.rssi / 254) * 100)}%` : "";
    const loss = link.loss === null ? "" : `LQ ${fixed(100 * (1 - link.loss), 0)}%`;
    setText(nodes.link, `${loss}${rssi}`.trim() || "LQ --");

    // Ages: the newest vehicle telemetry and the front camera's newest frame on screen
    // (video.js: its age when drawn, and the time since). A NO SIGNAL card is no frame:
    // then the camera's own figure from /api/cameras (none for a camera never seen).
    const tAge = ageOfNewest();
    const shownFrame = fpv.video && fpv.video.frames.front;
    const vAge = shownFrame && shownFrame.signal ? shownFrame.ageAtDrawS + (performance.now() - shownFrame.drawnAt) / 1000
      : cam && cam.last_frame_age_s !== null && cam.last_frame_age_s !== undefined
        ? cam.last_frame_age_s + (performance.now() - (fpv.camerasAt || performance.now())) / 1000 : null;
    setText(nodes.age, `TLM ${tAge === null ? "--" : tAge.toFixed(1) + "s"} VID ${vAge === null ? "--" : vAge.toFixed(1) + "s"}`);

    // Messages line and centre warnings (how long each shows: in the source's time).
    const now = msg.t_server_mono + feed.sourceSince();
    const recent = s.messages.recent.filter((m) => now - m.t_mono < MESSAGE_SHOWN_S);
    setText(nodes.messages, recent.slice(-MESSAGE_LINES)
      .map((m) => `${SEVERITY[m.severity] ?? "MSG"} ${m.text}`).join("\n"));
    const warnings = [];
    // Station down: every group ages, the GPS's too; only a vehicle heard can lose its GPS.
    const heard = feed.flowing() && !s.link.link_lost;
    if (!feed.socketOpen) warnings.push("STATION UNREACHABLE");
    else if (!heard) warnings.push("LINK LOST");
    if (low) warnings.push("LOW BATTERY");
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
  }

  applyHidden();
  raf = requestAnimationFrame(frame);
  return {
    stats,
    toggleMenu() { setMenuOpen(!menuOpen); },
    menuBox, // a page adds its own controls (the emergency buttons) here
    // Stop drawing (a hidden view) or start again.
    setRunning(on) {
      if (on === (raf !== 0)) return;
      cancelAnimationFrame(raf);
      raf = on ? requestAnimationFrame(frame) : 0;
      dirty = true;
    },
    // A page's own OSD line (e.g. the task step on the goggles), data-osd=<name>.
    setLine(name, text) {
      let node = lines.querySelector(`[data-osd="${name}"]`);
      if (!node) { node = el("div", { class: "osd-item", "data-osd": name }); lines.append(node); }
      setText(node, text);
    },
  };
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

// The link's packet loss, from the page's one GET /api/status (telemetry.js, every 2 s;
// not part of the vehicle state). Also whether the station is refusing MAVLink (datagrams
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

// Text on the canvases is drawn once per label into a small canvas, outlined, and then
// copied: shaping and stroking text on every frame is most of what a software canvas
// pays (benchmarks/osd_frame_cost.py). Labels: the ladder's and the tape's, a few dozen.
const sprites = new Map();
function label(text, px, bold = false) {
  const key = `${text}|${px}|${bold}`;
  let sprite = sprites.get(key);
  if (!sprite) {
    const font = `${bold ? "bold " : ""}${px}px ui-monospace, monospace`;
    const pad = Math.ceil(px / 4);
    const canvas = new OffscreenCanvas(1, 1);
    let ctx = canvas.getContext("2d");
    ctx.font = font;
    canvas.width = Math.ceil(ctx.measureText(text).width) + 2 * pad;
    canvas.height = Math.ceil(px * 1.3) + 2 * pad;
    ctx = canvas.getContext("2d"); // (resizing reset its state)
    ctx.font = font;
    ctx.textBaseline = "middle";
    ctx.lineJoin = "round";
    ctx.lineWidth = Math.max(2, px / 4.5);
    ctx.strokeStyle = "#000";
    ctx.fillStyle = "#fff";
    ctx.strokeText(text, pad, canvas.height / 2);
    ctx.fillText(text, pad, canvas.height / 2);
    // An ImageBitmap, not the canvas: a bitmap is immutable, so drawing it needs no copy.
    sprite = canvas.transferToImageBitmap();
    sprites.set(key, sprite);
  }
  return sprite;
}

// A path stroked twice, black and wide under the colour: an outline that reads over sky
// and grass, at the cost of a second stroke rather than a shadow blur.
function outlinedStroke(ctx, path, colour, width, dpr) {
  ctx.strokeStyle = "#000";
  ctx.lineWidth = width + 2 * dpr;
  ctx.stroke(path);
  ctx.strokeStyle = colour;
  ctx.lineWidth = width;
  ctx.stroke(path);
}

// The camera's tilt and vertical field of view (its settings, else none and the default),
// and from them, in `c`'s pixels, the focal length of the picture as its canvas shows it
// (object-fit contain or cover, centred; `cam.width`/`height`: the frames' size).
function pictureOptics(cam, img, fit, c) {
  const tiltDeg = cam && cam.tilt_up_deg != null ? cam.tilt_up_deg : 0;
  const vfovDeg = cam && cam.vfov_deg != null ? cam.vfov_deg : DEFAULT_VFOV_DEG;
  // A canvas (video.js) has the frames' size once it has drawn one (data-frames).
  const drawn = img && (img.naturalWidth !== undefined || img.dataset.frames);
  const iw = (drawn && (img.naturalWidth ?? img.width)) || (cam && cam.width) || 0;
  const ih = (drawn && (img.naturalHeight ?? img.height)) || (cam && cam.height) || 0;
  const W = c.width, H = c.height;
  let picH = H;
  if (iw > 0 && ih > 0) {
    const scale = fit === "cover" ? Math.max(W / iw, H / ih) : Math.min(W / iw, H / ih);
    picH = ih * scale;
  }
  const fPx = picH / 2 / Math.tan((vfovDeg * D2R) / 2);
  return { tiltDeg, vfovDeg, fPx, key: `${tiltDeg}|${vfovDeg}|${fPx.toFixed(1)}` };
}

// Horizon and pitch ladder where the camera sees them: a pinhole camera `tiltDeg` above
// the nose, its focal length `fPx`. The horizon is exact (a straight line, turned and
// offset as the camera's axes point); a rung at elevation e lies f*tan(elevation of the
// view's centre - e) from the centre, across the horizon.
function drawHorizon(c, roll, pitch, { tiltDeg, fPx }, dpr) {
  const ctx = c.getContext("2d");
  const W = c.width, H = c.height;
  ctx.clearRect(0, 0, W, H);
  if (roll === null || pitch === null) return;
  const r = roll * D2R, p = pitch * D2R, t = tiltDeg * D2R;
  // The world-up components of the camera's right, down and forward axes (body FRD, roll
  // then pitch; yaw turns nothing about the horizon).
  const upRight = -Math.cos(p) * Math.sin(r);
  const upDown = Math.sin(p) * Math.sin(t) - Math.cos(p) * Math.cos(r) * Math.cos(t);
  const upFwd = Math.sin(p) * Math.cos(t) + Math.cos(p) * Math.cos(r) * Math.sin(t);
  const centreElev = Math.asin(Math.max(-1, Math.min(1, upFwd))) / D2R;
  ctx.save();
  ctx.translate(W / 2, H / 2);
  ctx.rotate(Math.atan2(upRight, -upDown)); // the world turns against the vehicle's roll
  const offset = (elev) => fPx * Math.tan((centreElev - elev) * D2R); // nose up: goes down
  const solid = new Path2D(), dashed = new Path2D(); // the ladder: dashed below the horizon
  if (Math.abs(centreElev) < 89) {
    const y0 = offset(0);
    solid.moveTo(-W * 0.4, y0); solid.lineTo(-W * 0.06, y0); // with a gap for the aircraft
    solid.moveTo(W * 0.06, y0); solid.lineTo(W * 0.4, y0);
  }
  const labels = [];
  for (let e = -50; e <= 50; e += 10) {
    if (e === 0 || Math.abs(centreElev - e) >= 89) continue;
    const y = offset(e);
    if (Math.abs(y) > H * 0.4) continue; // only what is near the centre
    const path = e < 0 ? dashed : solid;
    path.moveTo(-W * 0.1, y); path.lineTo(-W * 0.04, y);
    path.moveTo(W * 0.04, y); path.lineTo(W * 0.1, y);
    labels.push([e, y]);
  }
  outlinedStroke(ctx, solid, "#fff", 2 * dpr, dpr);
  ctx.setLineDash([6 * dpr, 4 * dpr]);
  outlinedStroke(ctx, dashed, "#fff", 2 * dpr, dpr);
  ctx.setLineDash([]);
  for (const [e, y] of labels) {
    const sprite = label(String(e), Math.round(12 * dpr));
    ctx.drawImage(sprite, W * 0.105, y - sprite.height / 2);
  }
  ctx.restore();
  // The aircraft symbol where the nose points: the tilt below the picture's centre.
  const ny = H / 2 + fPx * Math.tan(t);
  const plane = new Path2D();
  plane.moveTo(W / 2 - W * 0.05, ny); plane.lineTo(W / 2 - W * 0.015, ny);
  plane.lineTo(W / 2, ny + 6 * dpr);
  plane.lineTo(W / 2 + W * 0.015, ny); plane.lineTo(W / 2 + W * 0.05, ny);
  outlinedStroke(ctx, plane, "#ffd24a", 3 * dpr, dpr);
}

const canvasFont = new WeakMap(); // canvas -> the font its context has now
const COMPASS = { 0: "N", 45: "NE", 90: "E", 135: "SE", 180: "S", 225: "SW", 270: "W", 315: "NW" };

function drawTape(c, hdg, dpr) {
  const ctx = c.getContext("2d");
  const W = c.width, H = c.height;
  ctx.clearRect(0, 0, W, H);
  if (hdg === null) return;
  const pxPerDeg = W / 90; // the tape shows 90 degrees
  const px = Math.round(13 * dpr);
  const ticks = new Path2D();
  const start = Math.ceil((hdg - 45) / 5) * 5;
  for (let d = start; d <= hdg + 45; d += 5) {
    const x = W / 2 + (d - hdg) * pxPerDeg;
    const deg = ((d % 360) + 360) % 360;
    ticks.rect(x - dpr, H * 0.55, 2 * dpr, deg % 15 === 0 ? H * 0.4 : H * 0.2);
    if (deg % 15 === 0) {
      // Only a label that fits whole: one cut at the tape's end misreads (NE as "E").
      const sprite = label(COMPASS[deg] ?? String(deg), px, true);
      const left = x - sprite.width / 2;
      if (left >= 0 && left + sprite.width <= W) ctx.drawImage(sprite, left, 0);
    }
  }
  ctx.fillStyle = "#fff";
  ctx.fill(ticks);
  // The heading itself, boxed over the centre of the tape (its one text drawn per frame).
  const text = String(Math.round(hdg) % 360).padStart(3, "0");
  ctx.fillStyle = "#000";
  ctx.fillRect(W / 2 - 22 * dpr, H * 0.5, 44 * dpr, H * 0.5);
  const font = `bold ${px}px ui-monospace, monospace`;
  if (canvasFont.get(c) !== font) { // setting a font parses it: only when it changed
    ctx.font = font;
    ctx.textAlign = "center";
    ctx.textBaseline = "middle";
    canvasFont.set(c, font);
  }
  ctx.fillStyle = "#ffd24a";
  ctx.fillText(text, W / 2, H * 0.75);
}

const view = document.querySelector("[data-osd-view]");
if (view) (window.fpv = window.fpv || {}).osd = mountOsd(view);
