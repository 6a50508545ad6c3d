// fpv-station sessions page: GET /api/sessions as a table; download as zip; delete
// (DELETE /api/sessions/{id}, with the control token if the station asks for one).
"use strict";

(() => {
  const TOKEN_KEY = "fpv.token";
  const tbody = document.querySelector("#sessions tbody");
  const $ = (id) => document.getElementById(id);

  function fmtSize(bytes) {
    const units = ["B", "kB", "MB", "GB", "TB"];
    let i = 0;
    while (bytes >= 1000 && i < units.length - 1) { bytes /= 1000; i++; }
    return `${bytes.toFixed(i ? 1 : 0)} ${units[i]}`;
  }

  function fmtDuration(s) {
    if (s == null) return "--";
    s = Math.round(s);
    const m = Math.floor(s / 60);
    return m ? `${m} min ${String(s % 60).padStart(2, "0")} s` : `${s} s`;
  }

  function quality(s) {
    const parts = [];
    if (s.telemetry_rows != null) parts.push(`${s.telemetry_rows} rows`);
    let bad = false;
    for (const cam of Object.keys(s.frames_written || {})) {
      const dropped = (s.frames_dropped || {})[cam] || 0;
      if (dropped) bad = true;
      const skew = (s.skew_p99_s || {})[cam];
      parts.push(`${cam} ${s.frames_written[cam]} frames` + (dropped ? ` (${dropped} dropped)` : "") +
        (skew != null ? `, skew p99 ${Math.round(skew * 1000)} ms` : ""));
    }
    return { text: parts.join(", ") || "--", bad };
  }

  function cell(tr, text, cls) {
    const td = document.createElement("td");
    td.textContent = text;
    if (cls) td.className = cls;
    tr.appendChild(td);
    return td;
  }

  async function remove(id) {
    if (!confirm(`Delete session ${id}? This cannot be undone.`)) return;
    const url = `/api/sessions/${encodeURIComponent(id)}`;
    const headers = () => {
      const t = localStorage.getItem(TOKEN_KEY);
      return t ? { Authorization: `Bearer ${t}` } : {};
    };
    let r = await fetch(url, { method: "DELETE", headers: headers() });
    if (r.status === 401) {
      const token = prompt("This station needs its control token:");
      if (!token) return;
      localStorage.setItem(TOKEN_KEY, token);
      r = await fetch(url, { method: "DELETE", headers: headers() });
    }
    if (!r.ok) {
      const body = await r.json().catch(() => ({}));
      alert(`Cannot delete: ${body.error_msg || r.statusText}`);
    }
    load();
  }

  async function load() {
    let sessions;
    try {
      const r = await fetch("/api/sessions", { cache: "no-store" });
      if (!r.ok) throw new Error(`${r.status} ${r.statusText}`);
      sessions = await r.json();
      $("error").hidden = true;
    } catch (err) {
      $("error").textContent = `Cannot list sessions: ${err.message}`;
      $("error").hidden = false;
      return;
    }
    tbody.replaceChildren();
    $("empty").hidden = sessions.length > 0;
    for (const s of sessions) {
      const tr = document.createElement("tr");
      tr.dataset.id = s.id;
      const start = s.start_wall != null ? new Date(s.start_wall * 1000).toLocaleString() : s.id;
      cell(tr, start).title = s.id;
      cell(tr, s.recording_now ? "recording..." : fmtDuration(s.duration_s), "num");
      cell(tr, s.source);
      cell(tr, fmtSize(s.size_bytes), "num");
      cell(tr, s.status, `status-${s.status}`).title = s.stop_reason || "";
      const q = quality(s);
      cell(tr, q.text, q.bad ? "quality-bad" : "");
      const actions = cell(tr, "");
      const dl = document.createElement("a");
      dl.href = `/api/sessions/${encodeURIComponent(s.id)}/download`;
      dl.textContent = "download";
      dl.className = "download";
      actions.appendChild(dl);
      actions.append(" ");
      const del = document.createElement("button");
      del.textContent = "delete";
      del.className = "delete";
      del.disabled = s.recording_now;
      del.addEventListener("click", () => remove(s.id));
      actions.appendChild(del);
      tbody.appendChild(tr);
    }
  }

  load();
  setInterval(load, 5000);
})();
