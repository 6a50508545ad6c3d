// fpv-station: what the OSD draws on its two canvases (osd.js), the horizon with its pitch
// ladder and the heading tape, where the front camera's picture shows them.
const D2R = Math.PI / 180;
// The camera's optics (its tilt above the nose and vertical field of view) come from its
// settings through GET /api/cameras (video.js cameras.latest); a camera that does not say
// is taken as looking along the nose with this field of view.
const DEFAULT_VFOV_DEG = 60;

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
export function pictureOptics(cam, img, fit, c) {
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
// view's centre - e) from the centre, across the horizon. The rungs stay near the centre,
// their labels clear of the heading tape `reach` pixels above it.
export function drawHorizon(c, roll, pitch, { tiltDeg, fPx }, dpr, reach) {
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
  const px = Math.round(12 * dpr);
  const limit = Math.min(H * 0.4, reach - label("10", px).height / 2);
  for (let e = -50; e <= 50; e += 10) {
    if (e === 0 || Math.abs(centreElev - e) >= 89) continue;
    const y = offset(e);
    if (Math.abs(y) > limit) continue;
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
    const sprite = label(String(e), px);
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
// A resized canvas has lost its drawing state, its font too.
export function canvasResized(c) { canvasFont.delete(c); }
const COMPASS = { 0: "N", 45: "NE", 90: "E", 135: "SE", 180: "S", 225: "SW", 270: "W", 315: "NW" };

export function drawTape(c, hdg, dpr) {
  const ctx = c.getContext("2d");
  const W = c.width, H = c.height;
  ctx.clearRect(0, 0, W, H);
  if (hdg === null) return;
  const px = Math.round(13 * dpr);
  // The tape shows 90 degrees, its ends inset by half the widest label so that the labels
  // there (NE and SE at 090) are drawn whole.
  const inset = Math.ceil(label("000", px, true).width / 2);
  const pxPerDeg = (W - 2 * inset) / 90;
  const ticks = new Path2D();
  const start = Math.ceil((hdg - 45) / 5) * 5;
  const marks = []; // [label, left x], the compass points first
  for (let d = start; d <= hdg + 45; d += 5) {
    const x = W / 2 + (d - hdg) * pxPerDeg;
    const deg = ((d % 360) + 360) % 360;
    ticks.rect(x - dpr, H * 0.55, 2 * dpr, deg % 15 === 0 ? H * 0.4 : H * 0.2);
    if (deg % 15 === 0) {
      const sprite = label(COMPASS[deg] ?? String(deg), px, true);
      marks[COMPASS[deg] ? "unshift" : "push"]([sprite, x - sprite.width / 2]);
    }
  }
  // Only a label that fits whole (one cut at the tape's end misreads: NE as "E"), and on a
  // narrow tape not one that would touch a label drawn already (a compass point's first).
  const drawn = [];
  const gap = 2 * dpr;
  for (const [sprite, left] of marks) {
    const right = left + sprite.width;
    if (left < 0 || right > W) continue;
    if (drawn.some(([l, r]) => left < r + gap && l < right + gap)) continue;
    ctx.drawImage(sprite, left, 0);
    drawn.push([left, right]);
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
