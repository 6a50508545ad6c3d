// The 3D trajectory panel on the pilot page: the viser client, served by the station's
// own viser server (no CDN), in an iframe inside #panel-3d. A toolbar button shows or
// hides it, a button in the panel enlarges it to the whole window. The iframe loads on
// first show only: the viewer is not free on a small laptop or goggles.
(function () {
  "use strict";

  const STYLE = `
    #panel-3d { display: flex; flex-direction: column; }
    #panel-3d:not([data-styled]) { position: fixed; right: .6rem; bottom: .6rem; top: 3.2rem;
      width: min(40rem, 60vw); background: #1b1f23; border: 1px solid #2a3036; z-index: 5; }
    #panel-3d[hidden] { display: none; }
    #panel-3d.p3d-large { left: .6rem !important; width: auto !important; z-index: 20; }
    #panel-3d .p3d-bar { display: flex; gap: .4rem; align-items: center; padding: .25rem .4rem;
      font: 13px system-ui, sans-serif; color: #e8eaed; }
    #panel-3d .p3d-bar span { margin-right: auto; opacity: .8; }
    #panel-3d .p3d-bar button, #p3d-toggle { background: #2a3036; color: #e8eaed;
      border: 1px solid #3a424a; border-radius: .3rem; padding: .2rem .6rem; cursor: pointer; }
    #panel-3d iframe { flex: 1; width: 100%; border: 0; background: #fff; }
    #p3d-toggle.p3d-floating { position: fixed; right: .6rem; top: .6rem; z-index: 6; }
  `;

  function el(tag, attrs, text) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
    if (text) e.textContent = text;
    return e;
  }

  async function init() {
    let info;
    try {
      const r = await fetch("/api/viser");
      info = await r.json();
    } catch (err) {
      return; // an older station without the panel: nothing to add
    }
    if (!info.enabled || !info.port) return;
    document.head.appendChild(el("style", {}, STYLE));

    let panel = document.getElementById("panel-3d");
    if (!panel) {
      panel = el("section", { id: "panel-3d", hidden: "" });
      document.body.appendChild(panel);
    } else if (getComputedStyle(panel).position === "fixed") {
      panel.setAttribute("data-styled", ""); // the page styles the panel itself
    }
    const url = `${location.protocol}//${location.hostname}:${info.port}/`;
    const bar = el("div", { class: "p3d-bar" });
    bar.appendChild(el("span", {}, "3D trajectory (ENU, origin = arming point)"));
    const big = el("button", { type: "button", id: "p3d-enlarge", title: "Enlarge" }, "Enlarge");
    const open = el("a", { href: url, target: "_blank", rel: "noopener" }, "");
    const openBtn = el("button", { type: "button", title: "Open in its own tab" }, "Tab");
    open.appendChild(openBtn);
    bar.append(big, open);
    const frame = el("iframe", { id: "p3d-frame", title: "3D trajectory" });
    panel.append(bar, frame);

    function show(visible) {
      panel.hidden = !visible;
      if (visible && !frame.getAttribute("src")) frame.setAttribute("src", url);
      toggle.classList.toggle("active", visible);
      try { localStorage.setItem("panel3d.visible", visible ? "1" : "0"); } catch (e) {}
    }
    big.addEventListener("click", () => {
      const large = panel.classList.toggle("p3d-large");
      big.textContent = large ? "Shrink" : "Enlarge";
    });

    const toggle = el("button", { type: "button", id: "p3d-toggle", title: "3D trajectory" }, "3D");
    const toolbar = document.getElementById("toolbar");
    if (toolbar) toolbar.appendChild(toggle);
    else { toggle.classList.add("p3d-floating"); document.body.appendChild(toggle); }
    toggle.addEventListener("click", () => show(panel.hidden));

    let remembered = null;
    try { remembered = localStorage.getItem("panel3d.visible"); } catch (e) {}
    if (remembered === "1" || new URLSearchParams(location.search).has("3d")) show(true);
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", init);
  else init();
})();
