// The video WebSocket of a page (web/video.js), off the page's main thread: its messages
// are received and decoded here, so a busy page (the OSD, layout, telemetry) never holds
// up a frame's arrival or its decode.
//
// Page -> worker: {type: "connect", url, ack} opens /ws/video?ack= (and reopens it a
// second after it closes); {type: "send", message} sends a message on it (a subscription,
// an ack).
// Worker -> page: {type: "connecting", generation} when a connection starts (the station
// counts its frames anew); {type: "open", generation}; {type: "frame", head, bitmap}, the
// decoded picture transferred (not copied) with its header and its times (ms since the
// epoch on this browser's clock: receivedAt, decodeFrom, decodedAt); {type: "skipped"} for
// a frame replaced before its decode or that did not decode (the page counts it handled).
//
// One decode per camera at a time; a frame that arrives meanwhile waits, and a newer one
// replaces it undecoded: a busy page spends no CPU on pictures it would not draw.
const decoder = new TextDecoder();
const cameras = {}; // name -> {decoding, waiting}
let ws = null;
let generation = 0;

const nowMs = () => performance.timeOrigin + performance.now();

function connect(url) {
  const sock = new WebSocket(url);
  sock.binaryType = "arraybuffer";
  ws = sock;
  generation += 1;
  for (const c of Object.values(cameras)) c.waiting = null;
  self.postMessage({ type: "connecting", generation });
  sock.onopen = () => self.postMessage({ type: "open", generation });
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
  const c = (cameras[head.camera] ??= { decoding: false, waiting: null });
  if (c.decoding) {
    if (c.waiting) self.postMessage({ type: "skipped" });
    c.waiting = { head, jpeg };
    return;
  }
  decode(c, head, jpeg);
}

function decode(c, head, jpeg) {
  c.decoding = true;
  head.decodeFrom = nowMs();
  createImageBitmap(new Blob([jpeg], { type: "image/jpeg" })).then((bitmap) => {
    head.decodedAt = nowMs();
    if (head.generation !== generation) { bitmap.close(); return; }
    self.postMessage({ type: "frame", head, bitmap }, [bitmap]);
  }, () => { if (head.generation === generation) self.postMessage({ type: "skipped" }); }).finally(() => {
    c.decoding = false;
    const next = c.waiting;
    c.waiting = null;
    if (next) decode(c, next.head, next.jpeg);
  });
}

self.onmessage = (e) => {
  const m = e.data;
  if (m.type === "connect") connect(m.url);
  else if (m.type === "send" && ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(m.message));
};
