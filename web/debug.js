// fpv-station pages: window.fpvDebug, what the Chromium tests and the benchmarks observe of
// a page beyond its DOM. Modules talk through imports and window events; each publishes
// here the live object that tests read, and no module reads it back (eslint.config.mjs
// keeps window.fpvDebug to this file).
//
//   fpvDebug.feed      telemetry.js `feed`: latest message, flowing(), ended, ...
//   fpvDebug.cameras   video.js `cameras`: GET /api/cameras figures, frames drawn, latency,
//                      log (an array to collect every latency sample: glass_to_glass.py)
//   fpvDebug.control   control.js sticks: {enabled, held, sticks, input, lastReply}
//   fpvDebug.osd       the page's OSD (osd.js): .stats, the cost of each frame
//                      (osd_frame_cost.py; with stats.raster set, the canvases are
//                      rasterized inside the timing)
//   fpvDebug.osdRight  the goggles' right eye's OSD, once stereo was switched on
//   fpvDebug.voice     voice.js: {heard, recording}, what its callouts are news against
//                      (nothing is said of the state a page finds on opening)
export function expose(name, value) {
  window.fpvDebug = window.fpvDebug || {};
  window.fpvDebug[name] = value;
}
