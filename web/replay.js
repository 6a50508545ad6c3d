// Replay of a recorded session: the whole path seen from above and its height against time,
// a time slider (and play at 1x-8x) that moves the vehicle along it and shows the front and
// bottom frames of that instant, and a second session overlaid in the paper's frame.
// Data: GET /api/sessions/{id}/trajectory (ENU metres, times, every frame's capture time).
// One time axis: the session clock, on which the recorder stamps rows and frames (seconds
// since the session started). The slider's instant shows the last fix at or before it (the
// fix the telemetry row of that instant holds) and the newest frame captured at or before
// it; before the first fix there is no vehicle to show.
// 3D: the station's replay viser server in an iframe, told what to show by
// PUT /api/replay3d and the slider's instant by PUT /api/replay3d/time (<= 15 Hz). That
// scene is shared by every viewer of the replay panel: the last page to move it wins.
// Colours: the path is drawn in the colours of the reply (the server's ramp, as the 3D
// panel's), the compared session in one colour.
import { $, api } from "/lib.js";

const params = new URLSearchParams(location.search);
const view = { a: null, b: null, gen: 0, t: 0, playing: false, anchorT: 0, anchorWall: 0, frames: {} };
const r3d = {
  path: null, loading: false, wanted: null, ready: false, sentT: null, lastSent: 0, timer: null, busy: false,
};
const R3D_PERIOD_MS = 1000 / 15;
const R3D_RETRY_MS = 1000; // after a PUT that failed

function status(text) { $("replay-status").textContent = text; }

async function loadSessions() {
  const sessions = await api("/api/sessions");
  for (const sel of [$("replay-session"), $("replay-compare")]) {
    for (const s of sessions) {
      const dur = s.duration_s != null ? ` (${Math.round(s.duration_s)} s)` : "";
      sel.appendChild(new Option(`${s.id}${dur}`, s.id));
    }
  }
  return sessions;
}

function trajUrl(id) {
  const align = $("replay-align").checked ? "?align=farthest" : "";
  return `/api/sessions/${encodeURIComponent(id)}/trajectory${align}`;
}

async function load() {
  const a = $("replay-session").value, b = $("replay-compare").value;
  const q = new URLSearchParams();
  if (a) q.set("session", a);
  if (b) q.set("compare", b);
  if ($("replay-align").checked) q.set("align", "1");
  history.replaceState(null, "", `${location.pathname}?${q}`);
  view.a = view.b = null;
  const gen = ++view.gen; // a newer pick supersedes this one, whichever answers first
  if (!a) { status("No recorded session yet."); draw(); return; }
  status(`Loading ${a}...`);
  let ta, tb;
  try {
    ta = await api(trajUrl(a));
    tb = b ? await api(trajUrl(b)) : null;
  } catch (err) {
    if (gen !== view.gen) return;
    status(`Cannot load the trajectory: ${err.message}`);
    draw();
    return;
  }
  if (gen !== view.gen) return;
  view.a = ta;
  view.b = tb;
  load3d(a, b);
  const dur = duration(view.a);
  $("replay-slider").max = String(Math.max(1, Math.round(dur * 10)));
  setTime(0);
  status(`${view.a.t_s.length} fixes, ${dur.toFixed(1)} s` +
    (view.b ? `; overlay ${view.b.id} (${view.b.t_s.length} fixes)` : ""));
}

// -- the 3D panel ------------------------------------------------------------------

async function init3d() {
  try {
    r3d.path = (await api("/api/viser")).replay_path; // null with --no-3d: the 2D view alone
  } catch (err) {
    status(`No 3D panel: ${err.message}`);
  }
}

// One load at a time, as for the instant below: two in flight may reach the station in
// either order and leave the panel on the older pick. A pick made meanwhile is sent
// once the load in flight has answered; the newest pick wins.
async function load3d(a, b) {
  if (!r3d.path) return;
  const frame = $("replay-3d");
  if (!frame.getAttribute("src")) {
    frame.hidden = false;
    frame.setAttribute("src", r3d.path); // the station's own door (server/trajectory3d/gate.py)
    draw(); // the canvas just got narrower
  }
  r3d.ready = false;
  r3d.wanted = { session: a, overlay: b || null, align: $("replay-align").checked ? "farthest" : "none" };
  if (r3d.loading) return;
  r3d.loading = true;
  while (r3d.wanted) {
    const body = r3d.wanted;
    r3d.wanted = null;
    try {
      await api("/api/replay3d", { method: "PUT", body });
      if (r3d.wanted) continue; // a newer pick: load that first
      r3d.ready = true;
      r3d.sentT = null;
      send3dTime();
    } catch (err) {
      status(`${$("replay-status").textContent} (3D: ${err.message})`);
    }
  }
  r3d.loading = false;
}

// Throttled: at most 15 PUTs a second while the slider moves or play runs, and the
// last instant is always sent. One PUT at a time: two in flight may reach the station in
// either order and leave the panel at the older instant. A failed one is sent again.
function send3dTime() {
  if (!r3d.ready || r3d.busy || r3d.sentT === view.t) return;
  const wait = r3d.lastSent + R3D_PERIOD_MS - performance.now();
  if (wait > 0) {
    if (!r3d.timer) r3d.timer = setTimeout(() => { r3d.timer = null; send3dTime(); }, wait);
    return;
  }
  r3d.lastSent = performance.now();
  r3d.sentT = view.t;
  r3d.busy = true;
  api("/api/replay3d/time", { method: "PUT", body: { t_s: view.t } })
    .catch(() => { r3d.sentT = null; r3d.lastSent = performance.now() + R3D_RETRY_MS; })
    .finally(() => { r3d.busy = false; send3dTime(); });
}

const duration = (tr) => tr.duration_s;

// Index of the last time in the sorted `times` at or before `t` (-1 before the first).
function lastAtOrBefore(times, t) {
  let lo = -1, hi = times.length - 1;
  while (lo < hi) {
    const mid = (lo + hi + 1) >> 1;
    if (times[mid] <= t) lo = mid; else hi = mid - 1;
  }
  return lo;
}

// The fix of `tr` shown at the instant `t` (session clock), -1 before its first fix.
const indexAt = (tr, t) => lastAtOrBefore(tr.t_s, t);

// The newest frame of `cam` captured at or before the instant `t`, or null.
function frameAt(tr, cam, t) {
  const index = tr.frame_index[cam];
  const k = index ? lastAtOrBefore(index.t_s, t) : -1;
  return k >= 0 ? index.file[k] : null;
}

function setTime(t) {
  view.t = Math.max(0, Math.min(t, view.a ? duration(view.a) : 0));
  $("replay-slider").value = String(Math.round(view.t * 10));
  $("replay-time").textContent = `${view.t.toFixed(1)} / ${view.a ? duration(view.a).toFixed(1) : "--"} s`;
  if (view.a) showInstant(view.a, view.t);
  draw();
  send3dTime();
}

function showInstant(tr, t) {
  const i = indexAt(tr, t);
  const fmt = (v, unit) => v == null || i < 0 ? "--" : `${v.toFixed(2)} ${unit}`;
  $("r-x").textContent = fmt(tr.x_m[i], "m");
  $("r-y").textContent = fmt(tr.y_m[i], "m");
  $("r-z").textContent = fmt(tr.z_m[i], "m");
  $("r-speed").textContent = fmt(tr.speed_mps[i], "m/s");
  for (const cam of ["front", "bottom"]) {
    const file = frameAt(tr, cam, t);
    const img = $(`replay-${cam}`);
    if (file && view.frames[cam] !== file) {
      view.frames[cam] = file;
      const path = file.split("/").map(encodeURIComponent).join("/");
      img.src = `/api/sessions/${encodeURIComponent(tr.id)}/files/${path}`;
    } else if (!file) { view.frames[cam] = null; img.removeAttribute("src"); }
  }
}

function fitCanvas(c) {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.max(1, Math.round(c.clientWidth * dpr)), h = Math.max(1, Math.round(c.clientHeight * dpr));
  if (c.width !== w || c.height !== h) { c.width = w; c.height = h; }
  const ctx = c.getContext("2d");
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.clearRect(0, 0, w, h);
  return { ctx, w, h, dpr };
}

// Draw a path as segments, broken where a gap starts (no fix, or a long silence).
function strokePath(ctx, tr, px, py, colorOf, width) {
  ctx.lineWidth = width;
  ctx.lineCap = "round";
  for (let i = 1; i < tr.t_s.length; i++) {
    if (tr.starts_run[i]) continue;
    ctx.strokeStyle = colorOf(i);
    ctx.beginPath();
    ctx.moveTo(px(tr, i - 1), py(tr, i - 1));
    ctx.lineTo(px(tr, i), py(tr, i));
    ctx.stroke();
  }
}

function drawTop() {
  const { ctx, w, h, dpr } = fitCanvas($("replay-top"));
  const trs = [view.a, view.b].filter(Boolean);
  if (!trs.length) return;
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (const tr of trs) for (let i = 0; i < tr.t_s.length; i++) {
    x0 = Math.min(x0, tr.x_m[i]); x1 = Math.max(x1, tr.x_m[i]);
    y0 = Math.min(y0, tr.y_m[i]); y1 = Math.max(y1, tr.y_m[i]);
  }
  const pad = 2, m = 20 * dpr;
  x0 -= pad; x1 += pad; y0 -= pad; y1 += pad;
  const s = Math.min((w - 2 * m) / (x1 - x0), (h - 2 * m) / (y1 - y0));
  const cx = (w - s * (x1 - x0)) / 2, cy = (h - s * (y1 - y0)) / 2;
  const X = (x) => cx + (x - x0) * s, Y = (y) => h - cy - (y - y0) * s;
  // 5 m grid, so distances read at a glance
  ctx.strokeStyle = "#d6dbd2"; ctx.lineWidth = 1;
  for (let gx = Math.ceil(x0 / 5) * 5; gx <= x1; gx += 5) { ctx.beginPath(); ctx.moveTo(X(gx), 0); ctx.lineTo(X(gx), h); ctx.stroke(); }
  for (let gy = Math.ceil(y0 / 5) * 5; gy <= y1; gy += 5) { ctx.beginPath(); ctx.moveTo(0, Y(gy)); ctx.lineTo(w, Y(gy)); ctx.stroke(); }
  ctx.fillStyle = "#555"; ctx.font = `${11 * dpr}px system-ui`;
  ctx.fillText(`grid 5 m; ${$("replay-align").checked ? "x = start to farthest point" : "x east, y north"}`, 6 * dpr, 14 * dpr);
  const px = (tr, i) => X(tr.x_m[i]), py = (tr, i) => Y(tr.y_m[i]);
  if (view.b) strokePath(ctx, view.b, px, py, () => "rgba(150, 60, 200, 0.55)", 3 * dpr);
  strokePath(ctx, view.a, px, py, (i) => view.a.color[i], 3 * dpr);
  // origin (arming point) and the vehicle(s) at the cursor time
  ctx.fillStyle = "#f5b400";
  ctx.beginPath(); ctx.arc(X(0), Y(0), 5 * dpr, 0, 2 * Math.PI); ctx.fill();
  for (const [tr, color] of [[view.b, "#9640c8"], [view.a, "#e02020"]]) {
    if (!tr) continue;
    const i = indexAt(tr, view.t);
    if (i < 0) continue; // no fix yet at this instant
    ctx.fillStyle = color; ctx.strokeStyle = "#fff"; ctx.lineWidth = 2 * dpr;
    ctx.beginPath(); ctx.arc(px(tr, i), py(tr, i), 7 * dpr, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
  }
}

function drawHeight() {
  const { ctx, w, h, dpr } = fitCanvas($("replay-height"));
  const trs = [view.a, view.b].filter(Boolean);
  if (!trs.length) return;
  const T = Math.max(...trs.map(duration), 1e-3);
  let z0 = 0, z1 = 1;
  for (const tr of trs) for (const z of tr.z_m) { z0 = Math.min(z0, z); z1 = Math.max(z1, z); }
  const m = 8 * dpr;
  const X = (t) => m + (t / T) * (w - 2 * m), Y = (z) => h - m - ((z - z0) / (z1 - z0)) * (h - 2 * m);
  const px = (tr, i) => X(tr.t_s[i]), py = (tr, i) => Y(tr.z_m[i]);
  if (view.b) strokePath(ctx, view.b, px, py, () => "rgba(150, 60, 200, 0.55)", 2 * dpr);
  strokePath(ctx, view.a, px, py, (i) => view.a.color[i], 2 * dpr);
  ctx.strokeStyle = "#e02020"; ctx.lineWidth = 1.5 * dpr;
  ctx.beginPath(); ctx.moveTo(X(view.t), 0); ctx.lineTo(X(view.t), h); ctx.stroke();
  ctx.fillStyle = "#555"; ctx.font = `${10 * dpr}px system-ui`;
  ctx.fillText(`height ${z0.toFixed(1)} to ${z1.toFixed(1)} m`, 6 * dpr, 12 * dpr);
}

function draw() { drawTop(); drawHeight(); }

// The playhead runs on the wall clock from where play started, so the replay keeps
// its speed however often the browser paints (slow laptops, background tabs).
function playhead() {
  return view.anchorT + (performance.now() - view.anchorWall) / 1000 * Number($("replay-speed").value);
}

function anchor() { view.anchorT = view.t; view.anchorWall = performance.now(); }

function tick() {
  if (!view.playing) return;
  setTime(playhead());
  if (view.a && view.t >= duration(view.a)) { togglePlay(false); return; }
  requestAnimationFrame(tick);
}

function togglePlay(on) {
  const was = view.playing;
  view.playing = on ?? !view.playing;
  $("replay-play").textContent = view.playing ? "Pause" : "Play";
  if (view.playing && !was) {
    if (view.a && view.t >= duration(view.a)) setTime(0);
    anchor();
    requestAnimationFrame(tick);
  } else if (!view.playing && was) {
    setTime(playhead());
  }
}

async function main() {
  $("replay-align").checked = params.get("align") === "1";
  $("replay-time").title = "session clock: seconds since the session started, as the " +
    "recorded rows and frames";
  await init3d();
  try {
    const sessions = await loadSessions();
    $("replay-session").value = params.get("session") || (sessions[0] && sessions[0].id) || "";
    $("replay-compare").value = params.get("compare") || "";
  } catch (err) {
    status(`Cannot list the sessions: ${err.message}`);
  }
  $("replay-session").addEventListener("change", load);
  $("replay-compare").addEventListener("change", () => {
    if ($("replay-compare").value) $("replay-align").checked = true; // compare in the paper's frame
    load();
  });
  $("replay-align").addEventListener("change", load);
  $("replay-slider").addEventListener("input", () => {
    setTime(Number($("replay-slider").value) / 10);
    anchor();
  });
  $("replay-speed").addEventListener("change", anchor);
  $("replay-play").addEventListener("click", () => togglePlay());
  window.addEventListener("resize", draw);
  await load();
}

main();
