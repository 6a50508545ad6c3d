// fpv-station pages: the front and bottom cameras in their views, each with its delivered
// fps and a latency readout.
//
//   import { cameras } from "/video.js";
//   cameras.latest      camera name -> its newest GET /api/cameras entry (delivered fps,
//                       settings, last_frame_age_s, signal), with latency_ms (p50) and
//                       clock_offset_s (station minus browser)
//   cameras.receivedAt  performance.now() of that reply: when last_frame_age_s was true
//   cameras.frames      camera name -> its newest frame drawn: {seq, t, signal, drawnAt
//                       (performance.now()), ageAtDrawS (its age when drawn, when clocks
//                       agree), width, height, drawn (count)}
//   cameras.latency     camera name -> {kind ("render" or "capture"), p50, p99, stationP50,
//                       stationP99, n}: milliseconds to the screen over the last WINDOW_MS
//   cameras.starved     the page's animation frames starve: it draws pictures as they
//                       come, and is sent STARVED_FPS (see below)
//   cameras.log         null, or an array that every latency sample is appended to, with
//                       its wait for a decode and the decode (benchmarks/glass_to_glass.py)
//   cameras.addTarget(camera, canvas)  another canvas showing a camera (the goggles'
//                       right eye), drawn from the same decoded frames
//
// A page's frames come over one WebSocket, /ws/video (server/routes/video_ws.py), not one
// MJPEG <img> per camera: Chromium gives a host six HTTP/1.1 connections, an MJPEG stream
// holds one for good, and a few pages' streams then starve every page's /api requests.
// The page subscribes to the cameras it shows (a hidden view, the goggles' hidden
// picture-in-picture or a hidden tab is not streamed). The socket lives in a worker
// (web/video-worker.js), which receives each binary message (one JPEG) and decodes it
// (createImageBitmap) off the page's main thread; the page draws the decoded picture onto
// the view's canvas in the next animation frame and tells the worker it is ready for more.
// A newer frame replaces one not yet decoded or not yet drawn, and the worker decodes at
// most two pictures ahead of the page's draws: a page decodes no faster than it draws.
// The page acknowledges, in its animation frames, every second frame drawn or replaced
// (?ack=4): at most four frames are on their way, so a busy page falls behind by frames
// skipped, never by a queue, and a page given few animation frames is sent few frames.
//
// A page whose animation frames starve is not left with old pictures. A tab that reads
// as visible but is not drawn (a background tab of headless Chromium; a window the
// compositor does not show) is given one animation frame a second: frames that waited
// for it were a second old when drawn. When a picture has waited STARVED_MS for its
// animation frame, the page draws it without one, asks the station for STARVED_FPS
// ({"max_fps"}, server/routes/video_ws.py) and from then on draws each picture as it
// is decoded, and acknowledges at once: its few pictures are fresh whenever the page
// renders. Two animation frames within PROMPT_MS of each other end it (the tab is in
// front again): full rate, drawn in animation frames.
//
// Once a second one cheap GET /api/cameras gives every camera's delivered fps and settings,
// and the station's clock (the reply's server_time checked against the request's round
// trip). A camera whose newest frame is older than STALLED_S reads "0 fps · stalled".
//
// Latency to the screen: the twin's frames carry their render time in a corner code
// (companion/cameras/frame_stamp.py), read from the decoded picture when it is drawn:
// render-to-screen ("R2S"). Other cameras' frames carry their capture time (the header's
// `t`): capture-to-screen ("C2S"). "Screen" is the animation frame the picture is drawn
// in; the display shows it at its next refresh. p50 and p99 over the last WINDOW_MS, and
// the station's share (render or capture until the message arrived), are in
// cameras.latency, on the camera's readout and, for the front camera, an OSD line (osd.js).
// A picture drawn outside an animation frame (a starved page) reaches the screen with the
// next one: its sample is taken then; one replaced before that was never shown.
// Times are on the station's clock (the browser's, corrected by the offset /api/cameras
// measures, when the two differ by more than its round trip).
import { expose } from "/debug.js";
import { $, el, api } from "/lib.js";

const CAMERAS = ["front", "bottom"];
const POLL_MS = 1000;
const CLOCK_SLACK_S = 0.02; // clocks "agree" if the offset is within RTT/2 + this
const STALLED_S = 1.0; // no new frame for this long: the stream is stalled, whatever fps says
const ACK_WINDOW = 4; // frames on their way at most (the station's ?ack=)
const WINDOW_MS = 5000; // latency figures over this long
// A page starves when a picture waits STARVED_MS for its animation frame, and starves no
// more when two come within PROMPT_MS: a page given a few animation frames a second (a
// busy phone) stays with them, and no rate between the two makes it switch back and forth.
const STARVED_MS = 500;
const PROMPT_MS = 250;
const STARVED_FPS = 5; // a starved page asks for each camera this often

const views = {};
for (const name of CAMERAS) {
  const canvas = videoCanvas(`${name} camera`, name);
  const readout = el("div", { class: "video-readout", id: `${name}-readout` }, "-- fps");
  $(`${name}-view`).append(canvas, readout);
  // pending: decoded, not yet drawn; last: the picture on the canvases, `unsampled` (its
  // header) until an animation frame has shown it.
  views[name] = { targets: [canvas], readout, pending: null, replaced: 0, drawnSeq: -1, last: null, unsampled: null };
}
const frames = {};
const samples = {}; // camera -> [{at, totalMs, stationMs}] over the last WINDOW_MS
const latency = {};
export const cameras = { latest: {}, receivedAt: 0, frames, latency, starved: false, log: null, addTarget };
expose("cameras", cameras);

function videoCanvas(label, name) {
  // 4x3 until the first frame: the view keeps a camera's usual shape while it waits.
  const canvas = el("canvas", { class: "video-stream", "aria-label": label, role: "img", width: 4, height: 3 });
  if (name) canvas.dataset.camera = name;
  return canvas;
}

function addTarget(name, canvas) {
  const v = views[name];
  if (!v) return;
  v.targets.push(canvas);
  if (frames[name] && v.last) drawOn(canvas, v.last);
  watchSize(canvas);
  subscribe();
}

// ---- the connection and the subscription ---------------------------------------------
const worker = new Worker("/video-worker.js", { type: "module" });
let open = false;
let handled = 0; // frames drawn, replaced or skipped by the worker (what the acks count)
let toAck = 0; // frames handled since the last acknowledge(), not yet in `handled`
let drawing = false; // an animation frame is requested
let starveTimer = 0; // set while a picture waits for an animation frame
let lastFrameAt = null; // performance.now() of the previous animation frame, while starved
let subscribed = "";
let clockOffset = { agree: false, offsetS: 0 };

function shown(v) {
  return document.visibilityState === "visible" && v.targets.some((c) => c.getClientRects().length > 0);
}

function subscribe() {
  const want = Object.keys(views).filter((n) => shown(views[n]));
  const maxFps = cameras.starved ? STARVED_FPS : null;
  const key = `${want.join(",")}@${maxFps}`;
  if (!open || key === subscribed) return;
  subscribed = key;
  worker.postMessage({ type: "send", message: { subscribe: want, max_fps: maxFps } });
}

function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  worker.postMessage({ type: "connect", url: `${proto}//${location.host}/ws/video?ack=${ACK_WINDOW}` });
}

// Messages keep their order: the worker says "connecting" before any frame of a new
// connection, and drops a decode of an older one that ends after it.
worker.onmessage = (e) => {
  const m = e.data;
  if (m.type === "frame") received(m.head, m.bitmap);
  else if (m.type === "skipped") done();
  else if (m.type === "open") {
    open = true;
    subscribe();
  } else if (m.type === "connecting") {
    // A new connection: a station that restarted counts its frames from 1 again.
    open = false;
    handled = 0;
    toAck = 0;
    subscribed = "";
    for (const v of Object.values(views)) {
      v.drawnSeq = -1;
      v.replaced = 0;
      if (v.pending) { v.pending.bitmap.close(); v.pending = null; }
    }
  }
};

// A decoded frame: drawn in the next animation frame, or at once while the page starves.
function received(head, bitmap) {
  const v = views[head.camera];
  if (!v) { bitmap.close(); return; }
  // The worker's times (ms since the epoch) on the station's clock.
  const onStation = (epochMs) => stationNowMs(epochMs - performance.timeOrigin);
  head.receivedMs = onStation(head.receivedAt);
  head.decodeFromMs = onStation(head.decodeFrom);
  head.decodedMs = onStation(head.decodedAt);
  if (head.seq <= v.drawnSeq) { // not newer than the picture on screen
    bitmap.close();
    ready(head, 1);
    done();
    return;
  }
  if (v.pending) {
    // Replaced before its animation frame: the worker hears of it at the draw, so a page
    // given few animation frames is given few pictures.
    v.pending.bitmap.close();
    v.replaced += 1;
    done();
  }
  v.pending = { head, bitmap };
  if (cameras.starved) {
    drawPictures();
  } else {
    nextFrame();
    if (!starveTimer) starveTimer = setTimeout(starving, STARVED_MS);
  }
}

function nextFrame() {
  if (!drawing) { drawing = true; requestAnimationFrame(animationFrame); }
}

// A picture waited STARVED_MS and no animation frame came.
function starving() {
  starveTimer = 0;
  if (!Object.values(views).some((v) => v.pending)) return;
  setStarved(true);
  drawPictures();
}

function setStarved(on) {
  cameras.starved = on;
  lastFrameAt = null;
  if (on) nextFrame(); // animation frames watched for the page's return to the front
  subscribe();
}

function ready(head, count) {
  worker.postMessage({ type: "ready", camera: head.camera, generation: head.generation, count });
}

// A frame handled: acknowledged in the next animation frame (at once while starved).
function done() {
  toAck += 1;
  if (cameras.starved) acknowledge(); else nextFrame();
}

function animationFrame() {
  drawing = false;
  const now = performance.now();
  clearTimeout(starveTimer);
  starveTimer = 0;
  if (cameras.starved) {
    if (lastFrameAt !== null && now - lastFrameAt < PROMPT_MS) setStarved(false);
    else { lastFrameAt = now; nextFrame(); }
  }
  drawPictures();
  // The pictures drawn since the last animation frame are shown with this one.
  for (const [name, v] of Object.entries(views)) {
    if (!v.unsampled) continue;
    noteLatency(name, v.unsampled, v.last, now);
    v.unsampled = null;
  }
}

// Each camera's pending picture onto its canvases: in an animation frame, or as it comes
// while the page starves.
function drawPictures() {
  const drawnAt = performance.now();
  for (const [name, v] of Object.entries(views)) {
    const p = v.pending;
    if (!p) continue;
    v.pending = null;
    ready(p.head, 1 + v.replaced); // the worker decodes the next while this one is drawn
    v.replaced = 0;
    for (const canvas of v.targets) if (canvas.getClientRects().length > 0) drawOn(canvas, p.bitmap);
    if (v.last) v.last.close();
    v.last = p.bitmap;
    v.unsampled = p.head;
    v.drawnSeq = p.head.seq;
    const wall = (performance.timeOrigin + drawnAt) / 1000;
    const prev = frames[name];
    frames[name] = {
      seq: p.head.seq, t: p.head.t, signal: p.head.signal, drawnAt,
      ageAtDrawS: clockOffset.agree ? Math.max(0, wall - p.head.t) : 0,
      width: p.bitmap.width, height: p.bitmap.height, drawn: (prev ? prev.drawn : 0) + 1,
    };
    for (const canvas of v.targets) canvas.dataset.frames = String(frames[name].drawn);
    window.dispatchEvent(new CustomEvent("fpv:frame", { detail: { camera: name, bitmap: p.bitmap, drawnAt, wall } }));
    toAck += 1;
  }
  acknowledge();
}

function acknowledge() {
  const before = handled;
  handled += toAck;
  toAck = 0;
  // Every second frame: the station reads half the acks for two more frames in flight.
  if (Math.floor(before / 2) !== Math.floor(handled / 2) && open) {
    worker.postMessage({ type: "send", message: { ack: handled } });
  }
}

// ---- latency to the screen -----------------------------------------------------------
function stationNowMs(at = performance.now()) {
  return performance.timeOrigin + at + (clockOffset.agree ? 0 : clockOffset.offsetS * 1000);
}

// The corner code of companion/cameras/frame_stamp.py: COLS x ROWS cells, each 1/64 of
// the width and 1/48 of the height; marker, counter, render ms mod 2^32, check nibble.
const STAMP = { cols: 14, rows: 4, perWidth: 64, perHeight: 48, marker: 0b1010 };
const TIME_MODULUS_MS = 2 ** 32;
let probe = null;
function readStamp(bitmap) {
  const W = bitmap.width, H = bitmap.height;
  const xs = [], ys = [];
  for (let c = 0; c <= STAMP.cols; c++) xs.push(Math.round((c * W) / STAMP.perWidth));
  for (let r = 0; r <= STAMP.rows; r++) ys.push(Math.round((r * H) / STAMP.perHeight));
  const w = xs[STAMP.cols], h = ys[STAMP.rows];
  if (w < STAMP.cols || h < STAMP.rows) return null;
  if (!probe) probe = document.createElement("canvas").getContext("2d", { willReadFrequently: true });
  if (probe.canvas.width !== w || probe.canvas.height !== h) { probe.canvas.width = w; probe.canvas.height = h; }
  probe.drawImage(bitmap, 0, 0, w, h, 0, 0, w, h);
  const data = probe.getImageData(0, 0, w, h).data;
  const nibbles = [];
  let nibble = 0;
  for (let r = 0; r < STAMP.rows; r++) {
    for (let c = 0; c < STAMP.cols; c++) {
      // The middle half of the cell: its edges are where JPEG and resizing blur.
      const qx = Math.floor((xs[c + 1] - xs[c]) / 4), qy = Math.floor((ys[r + 1] - ys[r]) / 4);
      let sum = 0, n = 0;
      for (let y = ys[r] + qy; y < ys[r + 1] - qy; y++) {
        for (let x = xs[c] + qx; x < xs[c + 1] - qx; x++) {
          const i = (y * w + x) * 4;
          sum += data[i] + data[i + 1] + data[i + 2];
          n += 3;
        }
      }
      nibble = nibble * 2 + (n && sum / n > 128 ? 1 : 0);
      if ((r * STAMP.cols + c) % 4 === 3) { nibbles.push(nibble); nibble = 0; }
    }
  }
  let check = 0;
  for (const x of nibbles.slice(0, -1)) check ^= x;
  if (nibbles[0] !== STAMP.marker || check !== nibbles[nibbles.length - 1]) return null;
  let t = 0;
  for (const x of nibbles.slice(5, -1)) t = t * 16 + x;
  const counter = nibbles.slice(1, 5).reduce((a, x) => a * 16 + x, 0);
  return { counter, tMs32: t };
}

function unwrapMs(tMs32, nearMs) {
  const base = nearMs - (nearMs % TIME_MODULUS_MS);
  let best = base + tMs32;
  for (const t of [best - TIME_MODULUS_MS, best + TIME_MODULUS_MS]) {
    if (Math.abs(t - nearMs) < Math.abs(best - nearMs)) best = t;
  }
  return best;
}

function noteLatency(name, head, bitmap, drawnAt) {
  const shownMs = stationNowMs(drawnAt);
  const code = readStamp(bitmap);
  const kind = code ? "render" : "capture";
  const fromMs = code ? unwrapMs(code.tMs32, shownMs) : head.t * 1000;
  const sample = { at: drawnAt, totalMs: shownMs - fromMs, stationMs: head.receivedMs - fromMs, kind };
  const list = (samples[name] = samples[name] || []);
  list.push(sample);
  while (list.length && list[0].at < drawnAt - WINDOW_MS) list.shift();
  if (cameras.log) {
    cameras.log.push({
      camera: name, seq: head.seq, counter: code ? code.counter : null, ...sample,
      fromMs, waitMs: head.decodeFromMs - head.receivedMs, decodeMs: head.decodedMs - head.decodeFromMs,
    });
  }
}

function percentile(sorted, q) {
  return sorted.length ? sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))] : null;
}

function summarise(name) {
  const now = performance.now();
  const list = (samples[name] || []).filter((x) => x.at >= now - WINDOW_MS);
  if (!list.length) { delete latency[name]; return; }
  const total = list.map((x) => x.totalMs).sort((a, b) => a - b);
  const station = list.map((x) => x.stationMs).sort((a, b) => a - b);
  latency[name] = {
    kind: list[list.length - 1].kind, n: list.length,
    p50: percentile(total, 0.5), p99: percentile(total, 0.99),
    stationP50: percentile(station, 0.5), stationP99: percentile(station, 0.99),
  };
}

function drawOn(canvas, bitmap) {
  if (canvas.width !== bitmap.width || canvas.height !== bitmap.height) {
    canvas.width = bitmap.width;
    canvas.height = bitmap.height;
  }
  canvas.getContext("2d").drawImage(bitmap, 0, 0);
}

// A view shown or hidden (the PiP, stereo's right eye, a phone turned) changes its
// canvas's size; a tab put in the background changes its visibility.
const resizes = new ResizeObserver(() => subscribe());
function watchSize(canvas) { resizes.observe(canvas); }
for (const v of Object.values(views)) v.targets.forEach(watchSize);
document.addEventListener("visibilitychange", () => subscribe());
connect();

// ---- figures -----------------------------------------------------------------------
async function poll() {
  const sentAt = Date.now();
  let reply;
  try {
    reply = await api("/api/cameras");
  } catch (err) {
    for (const v of Object.values(views)) setReadout(v, "0 fps · station unreachable", "bad");
    return;
  }
  subscribe();
  const now = Date.now();
  cameras.receivedAt = performance.now(); // when last_frame_age_s was true (the OSD ages it on)
  const rttS = (now - sentAt) / 1000;
  // Station clock minus browser clock, best estimate: server_time was taken mid-request.
  const offsetS = reply.server_time - (sentAt + now) / 2000;
  const clocksAgree = Math.abs(offsetS) <= rttS / 2 + CLOCK_SLACK_S;
  clockOffset = { agree: clocksAgree, offsetS };
  for (const name of CAMERAS) summarise(name);
  for (const cam of reply.cameras) {
    const lat = latency[cam.name] ?? null;
    const latencyMs = lat ? lat.p50 : null;
    cameras.latest[cam.name] = { ...cam, latency_ms: latencyMs, clock_offset_s: offsetS };
    const v = views[cam.name];
    if (!v) continue;
    if (!cam.signal) {
      // The frame itself says why, large; the readout stays short (hover for the reason).
      setReadout(v, "NO SIGNAL", "bad", cam.reason || "no frames");
      continue;
    }
    if (cam.last_frame_age_s === null || cam.last_frame_age_s > STALLED_S) {
      // Frames stopped: 0 fps now, not the average of the last seconds.
      const age = cam.last_frame_age_s === null ? "" : ` ${cam.last_frame_age_s.toFixed(0)} s`;
      setReadout(v, `0 fps · stalled${age}`, "bad");
      continue;
    }
    let text = `${cam.delivered_fps.toFixed(1)} fps`;
    if (lat) text += ` · ${lat.p50.toFixed(0)} ms · p99 ${lat.p99.toFixed(0)}`;
    if (!clocksAgree) text += ` · clock ${offsetS >= 0 ? "+" : ""}${offsetS.toFixed(2)} s`;
    const slow = cam.delivered_fps < 0.8 * cam.configured_fps;
    setReadout(v, text, slow ? "warn" : "");
  }
}

function setReadout(v, text, cls, title = "") {
  v.readout.textContent = text;
  v.readout.title = title;
  v.readout.className = `video-readout${cls ? " " + cls : ""}`;
}

poll();
setInterval(poll, POLL_MS);
