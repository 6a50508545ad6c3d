// What every page of fpv-station shares: one ES module, imported as
//   import { $, el, api, ApiError, wsUrl, liveSocket, askToken } from "/lib.js";
// from <script type="module"> (no build step, no CDN). The whole API:
//
//   $(id)                        document.getElementById(id)
//   el(tag, attrs, ...children)  a new element: attrs are attributes ("class", "id", "href",
//                                ...; true = present, false/null = absent), children are
//                                nodes or text
//   svgEl(tag, attrs, ...children)  the same for an SVG element (<svg>, <rect>, ...): what
//                                a script moves (a knob, a bar) moves by attributes,
//                                never by styles
//   token()                      the station's control token kept in this browser, or null
//                                (a ?token= in the page's URL is taken into it at load)
//   askToken(why)                ask the user for the token (a prompt), keep it; returns it,
//                                or null when the user declines
//   api(path, {method, body})    fetch a JSON API route (body: an object, sent as JSON) and
//                                return the parsed reply (null when there is none; images
//                                and streams are plain URLs, not api calls). Sends the token when there is one;
//                                on 401 asks for it once (askToken) and retries. A refusal
//                                throws ApiError; so does an unreachable station (status 0).
//   ApiError                     .status (HTTP, 0 = unreachable), .error (the server's error
//                                name, e.g. "Conflict"), .message (its error_msg)
//   wsUrl(path, {auth})          ws:// or wss:// URL of `path` on this station; with auth,
//                                the token rides as ?token= (browsers cannot set headers)
//   liveSocket(path, handlers)   a JSON WebSocket that reconnects (0.5 s doubling to 5 s):
//                                handlers {message(obj), open(), close()}; returns
//                                {send(obj), close()}: send is dropped while the socket
//                                is down, close stops it for good. E.g. telemetry with
//                                bounded staleness (server/routes/telemetry.py):
//                                  const tm = liveSocket("/ws/telemetry?ack=1",
//                                    { message(m) { draw(m); tm.send({ ack: m.version }); } });
//   CLOSE_UNAUTHORIZED           4401, the close code of a WebSocket that refuses the token:
//                                on it, askToken() and open the socket again (control.js)
//
// The server's error shape is {"error": Name, "error_msg": text} for every refusal
// (server/errors.py). Page scripts keep their own state; only what two pages need
// belongs here.

const TOKEN_KEY = "fpv.token";
export const CLOSE_UNAUTHORIZED = 4401;

export const $ = (id) => document.getElementById(id);

export function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === true) e.setAttribute(k, "");
    else if (v !== false && v !== null && v !== undefined) e.setAttribute(k, v);
  }
  e.append(...children);
  return e;
}

const SVG_NS = "http://www.w3.org/2000/svg";
export function svgEl(tag, attrs = {}, ...children) {
  const e = document.createElementNS(SVG_NS, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  e.append(...children);
  return e;
}

export const token = () => localStorage.getItem(TOKEN_KEY);

// `fpv-station serve` prints the station's URL with ?token= on first start (as Jupyter
// does): keep the token in this browser and take it out of the address bar, so that it
// is not bookmarked, shared or shown over the pilot's shoulder.
(function takeTokenFromUrl() {
  const url = new URL(location.href);
  const t = url.searchParams.get("token");
  if (!t) return;
  localStorage.setItem(TOKEN_KEY, t);
  url.searchParams.delete("token");
  history.replaceState(history.state, "", url.pathname + url.search + url.hash);
})();

export function askToken(why = "This station needs its control token:") {
  const t = prompt(why);
  if (!t) return null;
  localStorage.setItem(TOKEN_KEY, t);
  return t;
}

export class ApiError extends Error {
  constructor(status, error, message) {
    super(message);
    this.name = "ApiError";
    this.status = status;
    this.error = error;
  }
}

async function send(path, method, body) {
  const headers = {};
  const t = token();
  if (t) headers.Authorization = `Bearer ${t}`;
  if (body !== undefined) headers["Content-Type"] = "application/json";
  try {
    return await fetch(path, {
      method, headers, cache: "no-store",
      body: body === undefined ? undefined : JSON.stringify(body),
    });
  } catch (err) {
    throw new ApiError(0, "Unreachable", "the station is unreachable");
  }
}

export async function api(path, { method = "GET", body } = {}) {
  let r = await send(path, method, body);
  if (r.status === 401 && askToken()) r = await send(path, method, body);
  const text = await r.text();
  let reply;
  try {
    reply = text ? JSON.parse(text) : null;
  } catch (err) {
    // Not the station's JSON (a proxy's page, say): the status line is all there is.
    throw new ApiError(r.status, "HTTPError", `${r.status} ${r.statusText}`);
  }
  if (!r.ok && reply === null) throw new ApiError(r.status, "HTTPError", `${r.status} ${r.statusText}`);
  if (!r.ok) throw new ApiError(r.status, reply.error, reply.error_msg);
  return reply;
}

export function wsUrl(path, { auth = false } = {}) {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  const t = auth ? token() : null;
  const query = t ? `${path.includes("?") ? "&" : "?"}token=${encodeURIComponent(t)}` : "";
  return `${proto}//${location.host}${path}${query}`;
}

export function liveSocket(path, { message, open, close } = {}) {
  let socket = null, stopped = false, retryMs = 500;
  function connect() {
    socket = new WebSocket(wsUrl(path));
    socket.onopen = () => { retryMs = 500; if (open) open(); };
    socket.onmessage = (ev) => {
      let obj;
      try { obj = JSON.parse(ev.data); } catch (err) { console.warn(`bad message on ${path}`, err); return; }
      if (message) message(obj);
    };
    socket.onclose = () => {
      if (close) close();
      if (stopped) return;
      setTimeout(connect, retryMs);
      retryMs = Math.min(retryMs * 2, 5000);
    };
  }
  connect();
  return {
    send(obj) { if (socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(obj)); },
    close() { stopped = true; socket.close(); },
  };
}
