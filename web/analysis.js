// The paper's task analysis of recorded sessions: the table from GET /api/analysis, the
// figures from /api/analysis/{plot}.png. ?sessions=ID&task=...&reference=LAT,LON
// preselects (a link to a comparison).
import { $, el, api } from "/lib.js";

const PLOTS = ["trajectory3d", "birdseye", "history"];
const PLATFORM = { physical: "Physical quadcopter", twin: "Digital twin" };

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
    hr.appendChild(el("th", {}, h));
  }
  for (const r of data.results) {
    const tr = body.insertRow();
    const cells = [PLATFORM[r.platform] || r.platform, r.label,
      ...data.columns.map((c) => fmt(r[c.field]))];
    for (const c of cells) tr.insertCell().textContent = c;
  }
  const figs = $("figures");
  figs.replaceChildren();
  for (const plot of PLOTS) figs.appendChild(el("img", { alt: plot, src: `/api/analysis/${plot}.png?${q}` }));
  $("result").hidden = false;
}

async function analyse(ev) {
  if (ev) ev.preventDefault();
  const q = query();
  showError("");
  $("result").hidden = true;
  try {
    render(await api(`/api/analysis?${q}`), q);
  } catch (err) {
    showError(`${err.error}: ${err.message}`);
  }
}

async function init() {
  const pre = new URLSearchParams(location.search);
  if (pre.get("task")) $("task").value = pre.get("task");
  if (pre.get("reference")) $("reference").value = pre.get("reference");
  const wanted = new Set(pre.getAll("sessions"));
  let sessions;
  try {
    sessions = await api("/api/sessions");
  } catch (err) {
    return showError(`Cannot list sessions: ${err.message}`);
  }
  for (const s of sessions) {
    const opt = new Option(`${s.id} (${s.source})`, s.id, false, wanted.has(s.id));
    $("sessions").add(opt);
  }
  $("form").addEventListener("submit", analyse);
  if (wanted.size) analyse();
}

init();
