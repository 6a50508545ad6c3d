// The 3D trajectory panel on the pilot page: the viser client, served through the
// station's own server (/3d/live/, no CDN), in an iframe inside #panel-3d. A toolbar
// button shows or hides it, a button in the panel enlarges it to the whole window. The
// iframe loads on first show only: the viewer is not free on a small laptop or goggles.
import { $, el, api, token } from "/lib.js";

const VISIBLE_KEY = "panel3d.visible";

// viser's client connects to its page's own path (ws://host/3d/live), or to the URL in its
// ?websocket=: with the station's token there, the panel's controls act (they change
// what every viewer sees); without, it watches. The token is encoded twice: the page's
// query decodes it once, and the server's log redacts any `token=` it shows.
function panelUrl(path, t = token()) {
  if (!t) return path;
  const ws = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}${path.replace(/\/$/, "")}`;
  return `${path}?websocket=${ws}?token=${encodeURIComponent(encodeURIComponent(t))}`;
}

const info = await api("/api/viser");
if (info.enabled) {
  const panel = $("panel-3d");
  const url = panelUrl(info.path);
  const big = el("button", { type: "button", id: "p3d-enlarge", title: "Enlarge" }, "Enlarge");
  // Its own tab watches (no token in an address bar); the panel here has the controls.
  const open = el("a", { href: info.path, target: "_blank", rel: "noopener" },
    el("button", { type: "button", title: "Open in its own tab" }, "Tab"));
  const frame = el("iframe", { id: "p3d-frame", title: "3D trajectory" });
  panel.append(
    el("div", { class: "p3d-bar" }, el("span", {}, "3D trajectory (ENU, origin = arming point)"), big, open),
    frame,
  );
  const toggle = el("button", { type: "button", id: "p3d-toggle", title: "3D trajectory" }, "3D");
  $("toolbar").appendChild(toggle);

  const show = (visible) => {
    panel.hidden = !visible;
    if (visible && !frame.getAttribute("src")) frame.setAttribute("src", url);
    toggle.classList.toggle("active", visible);
    localStorage.setItem(VISIBLE_KEY, visible ? "1" : "0");
  };
  big.addEventListener("click", () => {
    big.textContent = panel.classList.toggle("p3d-large") ? "Shrink" : "Enlarge";
  });
  toggle.addEventListener("click", () => show(panel.hidden));
  if (localStorage.getItem(VISIBLE_KEY) === "1" || new URLSearchParams(location.search).has("3d")) {
    show(true);
  }
}
