// The paper's task analysis of recorded sessions: the table from GET /api/analysis, the
// figures from /api/analysis/{plot}.png. ?sessions=ID&task=...&reference=LAT,LON
// preselects (a link to a comparison). Without a task in the link, the task is the one
// the chosen session was flown as (its session.json `task`), until the user picks one.
// Columns where a smaller figure is the better flight are marked; a trial that does not
// count (a crash, an obstacle touched, a landing off the pad) says so and why.
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

const LOWER = "\u2193"; // marks a column where lower is better

const legend = el("p", { id: "legend", class: "note" });
const invalid = el("ul", { id: "invalid", class: "flags" });
$("table").after(legend, invalid);

function render(data, q) {
  $("title").textContent = data.title;
  const head = $("table").tHead, body = $("table").tBodies[0];
  head.replaceChildren();
  body.replaceChildren();
  const hr = head.insertRow();
  hr.append(el("th", {}, "Platform used"), el("th", {}, "Session"));
  for (const c of data.columns) {
    const th = el("th", { "data-field": c.field }, c.lower_is_better ? `${c.heading} ${LOWER}` : c.heading);
    if (c.lower_is_better) th.title = "lower is better";
    hr.appendChild(th);
  }
  for (const r of data.results) {
    const tr = body.insertRow();
    tr.dataset.valid = String(r.valid);
    if (!r.valid) tr.className = "invalid";
    const cells = [PLATFORM[r.platform] || r.platform, r.label,
      ...data.columns.map((c) => (c.field === "valid" ? (r.valid ? "valid" : "invalid") : fmt(r[c.field])))];
    for (const c of cells) tr.insertCell().textContent = c;
  }
  const lower = data.columns.filter((c) => c.lower_is_better).map((c) => c.heading);
  legend.textContent = lower.length ? `${LOWER} lower is better: ${lower.join(", ")}.` : "";
  invalid.replaceChildren(...data.results.filter((r) => !r.valid).map((r) =>
    el("li", { "data-flag": "invalid" }, el("b", {}, `${r.label} is not valid:`), ` ${r.invalid_reasons.join("; ")}`)));
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

// The task the first chosen session was flown as (its analysis), else null.
function sessionTask(byId) {
  for (const opt of $("sessions").selectedOptions) {
    const s = byId.get(opt.value);
    if (s && s.task && s.task.analysis) return s.task.analysis;
  }
  return null;
}

async function init() {
  const pre = new URLSearchParams(location.search);
  let taskChosen = Boolean(pre.get("task")); // by the link or by hand: then it stays
  if (taskChosen) $("task").value = pre.get("task");
  if (pre.get("reference")) $("reference").value = pre.get("reference");
  const wanted = new Set(pre.getAll("sessions"));
  let sessions;
  try {
    sessions = await api("/api/sessions");
  } catch (err) {
    return showError(`Cannot list sessions: ${err.message}`);
  }
  const byId = new Map(sessions.map((s) => [s.id, s]));
  for (const s of sessions) {
    const opt = new Option(`${s.id} (${s.source})`, s.id, false, wanted.has(s.id));
    $("sessions").add(opt);
  }
  const followSessions = () => {
    const task = taskChosen ? null : sessionTask(byId);
    if (task) $("task").value = task;
  };
  followSessions();
  $("sessions").addEventListener("change", followSessions);
  $("task").addEventListener("change", () => { taskChosen = true; });
  $("form").addEventListener("submit", analyse);
  if (wanted.size) analyse();
}

init();
