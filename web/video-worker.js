// The video WebSocket of a page (web/video.js), off the page's main thread: its messages
// are received and decoded here, so a busy page (the OSD, layout, telemetry) never holds
// up a frame's arrival or its decode.
//
// Page -> worker: {type: "connect", url, ack} opens /ws/video?ack= (and reopens it a
// second after it closes); {type: "send", message} sends a message on it (a subscription,
// an ack); {type: "ready", camera, generation, count} when the page has drawn, replaced or
// dropped `count` of the camera's pictures it was given.
// Worker -> page: {type: "connecting", generation} when a connection starts (the station
// counts its frames anew); {type: "open"}; {type: "frame", head, bitmap}, the decoded
// picture transferred (not copied) with its header, its connection's generation and its
// times (ms since the epoch on this browser's clock: receivedAt, decodeFrom, decodedAt);
// {type: "skipped"} for a frame replaced before its decode or that did not decode (the
// page counts it handled).
//
// Per camera, one decode at a time and at most IN_PAGE pictures in the page not yet drawn:
// a frame that arrives meanwhile waits, and a newer one replaces it undecoded. So the next
// picture is decoded while one waits for its animation frame, and a page decodes no
// faster than it draws: one that is given few animation frames (a busy phone) spends no
// CPU on pictures it would not draw.
const IN_PAGE = 2;
const decoder = new TextDecoder();
const cameras = {}; // name -> {decoding, inPage (pictures not yet drawn), waiting}
let ws = null;
let generation = 0;

const nowMs = () => performance.timeOrigin + performance.now();

function connect(url) {
  const sock = new WebSocket(url);
  sock.binaryType = "arraybuffer";
  ws = sock;
  generation += 1;
  for (const c of Object.values(cameras)) Object.assign(c, { decoding: false, inPage: 0, waiting: null });
  self.postMessage({ type: "connecting", generation });
  sock.onopen = () => self.postMessage({ type: "open" });
  sock.onmessage = (e) => { if (typeof e.data !== "string") receive(e.data); };
  sock.onclose = () => {
    if (ws === sock) ws = null;
    setTimeout(() => connect(url), 1000); // the station restarted, or the page was refused
  };
}

function receive(buf) {
  const receivedAt = nowMs();
  const headLen = new DataView(buf).getUint16(0);
  const head = JSON.parse(decoder.decode(new Uint8Array(buf, 2, headLen)));
  Object.assign(head, { receivedAt, generation });
  const jpeg = new Uint8Array(buf, 2 + headLen);
  const c = (cameras[head.camera] ??= { decoding: false, inPage: 0, waiting: null });
  if (c.waiting) self.postMessage({ type: "skipped" });
  c.waiting = { head, jpeg };
  next(c);
}

// Decode the frame that waits, if the camera has room for it.
function next(c) {
  if (c.decoding || c.inPage >= IN_PAGE || !c.waiting) return;
  const { head, jpeg } = c.waiting;
  c.waiting = null;
  c.decoding = true;
  head.decodeFrom = nowMs();
  createImageBitmap(new Blob([jpeg], { type: "image/jpeg" })).then((bitmap) => {
    head.decodedAt = nowMs();
    if (head.generation !== generation) { bitmap.close(); return; }
    c.inPage += 1;
    self.postMessage({ type: "frame", head, bitmap }, [bitmap]);
  }, () => {
    if (head.generation === generation) self.postMessage({ type: "skipped" });
  }).finally(() => {
    if (head.generation !== generation) return; // connect() has reset the camera
    c.decoding = false;
    next(c);
  });
}

self.onmessage = (e) => {
  const m = e.data;
  if (m.type === "connect") connect(m.url);
  else if (m.type === "send" && ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(m.message));
  else if (m.type === "ready" && m.generation === generation && cameras[m.camera]) {
    const c = cameras[m.camera];
    c.inPage -= m.count; // exact: a ready of an older connection is not counted
    next(c);
  }
};
