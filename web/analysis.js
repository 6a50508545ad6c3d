// The paper's task analysis of recorded sessions: the table from GET /api/analysis, the
// figures from /api/analysis/{plot}.png. ?sessions=ID&task=...&reference=LAT,LON
// preselects (links from the sessions page).
(() => {
  "use strict";
  const PLOTS = ["trajectory3d", "birdseye", "history"];
  const PLATFORM = { physical: "Physical quadcopter", twin: "Digital twin" };
  const $ = (id) => document.getElementById(id);

  function query() {
    const q = new URLSearchParams();
    q.set("task", $("task").value);
    for (const opt of $("sessions").selectedOptions) q.append("sessions", opt.value);
    const ref = $("reference").value.trim();
    if (ref) q.set("reference", ref);
    return q;
  }

  function fmt(v) {
    if (v === null || v === undefined) return "-";
    if (typeof v === "number" && !Number.isInteger(v)) return v.toFixed(Math.abs(v) < 100 ? 3 : 1);
    return String(v);
  }

  function showError(text) {
    $("error").textContent = text;
    $("error").hidden = !text;
  }

  function render(data, q) {
    $("title").textContent = data.title;
    const head = $("table").tHead, body = $("table").tBodies[0];
    head.replaceChildren();
    body.replaceChildren();
    const hr = head.insertRow();
    for (const h of ["Platform used", "Session", ...data.columns.map((c) => c.heading)]) {
      const th = document.createElement("th");
      th.textContent = h;
      hr.appendChild(th);
    }
    for (const r of data.results) {
      const tr = body.insertRow();
      const cells = [PLATFORM[r.platform] || r.platform, r.label,
        ...data.columns.map((c) => fmt(r[c.field]))];
      for (const c of cells) tr.insertCell().textContent = c;
    }
    const figs = $("figures");
    figs.replaceChildren();
    for (const plot of PLOTS) {
      const img = document.createElement("img");
      img.alt = plot;
      img.src = `/api/analysis/${plot}.png?${q}`;
      figs.appendChild(img);
    }
    $("result").hidden = false;
  }

  async function analyse(ev) {
    if (ev) ev.preventDefault();
    const q = query();
    showError("");
    $("result").hidden = true;
    const r = await fetch(`/api/analysis?${q}`, { cache: "no-store" });
    const data = await r.json();
    if (!r.ok) return showError(`${data.error}: ${data.error_msg}`);
    render(data, q);
  }

  async function init() {
    const pre = new URLSearchParams(location.search);
    if (pre.get("task")) $("task").value = pre.get("task");
    if (pre.get("reference")) $("reference").value = pre.get("reference");
    const wanted = new Set(pre.getAll("sessions"));
    const r = await fetch("/api/sessions", { cache: "no-store" });
    if (!r.ok) return showError("Cannot list sessions.");
    for (const s of await r.json()) {
      const opt = new Option(`${s.id} (${s.source})`, s.id, false, wanted.has(s.id));
      $("sessions").add(opt);
    }
    $("form").addEventListener("submit", analyse);
    if (wanted.size) analyse();
  }

  init();
})();
