// fpv-station pilot page: the front and bottom camera streams (MJPEG) in their views,
// each with its delivered fps and a latency readout.
//
// The streams are plain <img> elements on /video/{camera}.mjpg: the browser decodes the
// JPEGs natively, and the server skips frames for a viewer that falls behind. Once a
// second one cheap GET /api/cameras gives every camera's delivered fps and the capture
// time of its newest frame; latency = browser clock at arrival - that capture time (the
// age of the newest frame as the browser gets it: capture, encode, network, up to one
// frame interval of waiting), shown only when the browser's and station's clocks agree
// (the reply's server_time checked against the request's round trip). Others read the
// figures from window.fpv.cameras (and window.fpv.camerasAt: performance.now() of the
// reply). A camera whose newest frame is older than STALLED_S reads "0 fps · stalled".
import { $, el, api } from "/lib.js";

const CAMERAS = ["front", "bottom"];
const POLL_MS = 1000;
const CLOCK_SLACK_S = 0.02; // clocks "agree" if the offset is within RTT/2 + this
const STALLED_S = 1.0; // no new frame for this long: the stream is stalled, whatever fps says
const fpv = (window.fpv = window.fpv || {});
fpv.cameras = {};

const views = {};
for (const name of CAMERAS) {
  const img = el("img", { class: "video-stream", alt: `${name} camera`, "data-camera": name });
  const readout = el("div", { class: "video-readout", id: `${name}-readout` }, "-- fps");
  $(`${name}-view`).append(img, readout);
  views[name] = { img, readout, retry: null };
}
// Streams start after the page's load event: an endless MJPEG image would otherwise
// hold that event (and whatever waits for it) forever.
const start = () => Object.keys(views).forEach(attach);
if (document.readyState === "complete") start();
else window.addEventListener("load", start, { once: true });

// (Re)connect a stream; a broken stream (station restarted) retries once a second.
function attach(name) {
  const v = views[name];
  v.img.onerror = () => {
    if (v.retry) return;
    v.retry = setTimeout(() => { v.retry = null; attach(name); }, 1000);
  };
  v.img.src = `/video/${name}.mjpg?t=${Date.now()}`;
}

let stationDown = false;

async function poll() {
  const sentAt = Date.now();
  let reply;
  try {
    reply = await api("/api/cameras");
  } catch (err) {
    for (const v of Object.values(views)) setReadout(v, "0 fps · station unreachable", "bad");
    stationDown = true;
    return;
  }
  if (stationDown) {
    // The station is back (restarted): a stream that ended quietly will not error,
    // so reconnect every stream.
    stationDown = false;
    Object.keys(views).forEach(attach);
  }
  const now = Date.now();
  fpv.camerasAt = performance.now(); // when last_frame_age_s was true (the OSD ages it on)
  const rttS = (now - sentAt) / 1000;
  // Station clock minus browser clock, best estimate: server_time was taken mid-request.
  const offsetS = reply.server_time - (sentAt + now) / 2000;
  const clocksAgree = Math.abs(offsetS) <= rttS / 2 + CLOCK_SLACK_S;
  for (const cam of reply.cameras) {
    const latencyMs = cam.last_frame_time != null ? now - cam.last_frame_time * 1000 : null;
    fpv.cameras[cam.name] = { ...cam, latency_ms: clocksAgree ? latencyMs : null,
      clock_offset_s: offsetS };
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
    if (clocksAgree && latencyMs != null) text += ` · ${Math.max(0, latencyMs).toFixed(0)} ms`;
    else text += ` · clocks differ ${offsetS >= 0 ? "+" : ""}${offsetS.toFixed(2)} s`;
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
