// fpv-station sessions page: GET /api/sessions as a table; replay, download as zip,
// delete (DELETE /api/sessions/{id}; lib.js asks for the control token when needed).
// A session's status says how its recording ended (complete, recovered after the station
// died, cut short by a failed write); its quality column lists the station's flags
// (companion/recording/flags.py: a crash, a failsafe, telemetry gaps, link loss, dropped
// frames; each with its reason and threshold) or "ok" with the counts. A crashed flight's
// row is marked. Each session links to its analysis (which opens as the task it was flown as), and
// its score says whether the trial counts. Its onboard log column shows the autopilot's
// own log fetched into it (server/onboard_logs.py): the file, the progress of the download
// under way (GET /api/onboard_log, every second while one runs), or a button to fetch it.
// Its pilot column says who flew a demonstration (session.json "demonstration": a person's
// name, or the twin's scripted pilot); session-select.js selects sessions by task, pilot
// and score and exports them, and the table then shows only those.
import { $, el, api } from "/lib.js";
import { selection, onSelection, knownPilots, refreshSelection } from "/session-select.js";

const tbody = document.querySelector("#sessions tbody");

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

// The counts behind the flags (the cell's tooltip, and its text when nothing is flagged).
function counts(s) {
  const parts = [];
  if (s.telemetry_rows != null) parts.push(`${s.telemetry_rows} rows`);
  for (const cam of Object.keys(s.frames_written)) {
    const dropped = s.frames_dropped[cam] || 0;
    const skew = s.skew_p99_s[cam];
    parts.push(`${cam} ${s.frames_written[cam]} frames` + (dropped ? ` (${dropped} dropped)` : "") +
      (skew != null ? `, skew p99 ${Math.round(skew * 1000)} ms` : ""));
  }
  return parts.join(", ");
}

function qualityCell(tr, s) {
  const td = cell(tr, "", s.flags.length ? "quality-bad" : "quality-ok");
  td.title = counts(s);
  if (!s.flags.length) td.textContent = s.status === "unreadable" ? "--" : `ok: ${td.title || "no data"}`;
  else td.append(el("ul", { class: "flags" },
    ...s.flags.map((f) => el("li", { "data-flag": f.kind }, el("b", {}, f.kind.replace("_", " ")), ` ${f.reason}`))));
}

const STATUS = { complete: "complete", cut_short: "cut short", recording: "recording", unreadable: "unreadable" };
function statusText(s) {
  if (s.status === "interrupted") return s.recovered ? "recovered" : "interrupted";
  return STATUS[s.status] ?? s.status;
}

function scoreText(s) {
  // The trial's score, done by the station when the vehicle disarmed (server/trials.py).
  if (!s.score) return s.task ? "not scored" : "--";
  if (!s.score.ok) return "no score";
  const r = s.score.result;
  const main = s.score.task === "hover"
    ? `hover ${r.hover_distance_m.toFixed(3)} m`
    : `lateral ${r.lateral_deviation_m.toFixed(3)} m`;
  const figures = `${main}, height ${r.height_deviation_m.toFixed(3)} m, ${r.trial_time_s.toFixed(1)} s`;
  return r.valid === false ? `invalid: ${figures}` : figures;
}

function scoreTitle(s) {
  if (!s.score) return "";
  if (!s.score.ok) return s.score.reason || "";
  const r = s.score.result;
  const parts = [];
  if (r.valid === false) parts.push(`not valid: ${r.invalid_reasons.join("; ")}`);
  if (r.landing_accuracy_m != null) parts.push(`landed ${r.landing_accuracy_m.toFixed(2)} m from pad ${r.landing_pad}`);
  parts.push("lower is better");
  return parts.join("; ");
}

function cell(tr, text, cls) {
  const td = el("td", { class: cls || null }, text);
  tr.appendChild(td);
  return td;
}

async function remove(id) {
  if (!confirm(`Delete session ${id}? This cannot be undone.`)) return;
  try {
    await api(`/api/sessions/${encodeURIComponent(id)}`, { method: "DELETE" });
  } catch (err) {
    alert(`Cannot delete: ${err.message}`);
  }
  load();
}

// The autopilot's log as session.json has it, or the download under way.
const ACTIVE = new Set(["listing", "downloading"]);
let progressTimer = null;

function onboardCell(td, s, live) {
  td.replaceChildren();
  td.title = "";
  if (live && live.session === s.id && ACTIVE.has(live.state)) {
    const pct = live.size_bytes ? Math.floor((100 * live.received_bytes) / live.size_bytes) : 0;
    td.append(el("progress", { max: 100, value: pct }), ` ${live.state === "listing" ? "listing" : `${pct} %`}`);
    td.title = live.message;
    return;
  }
  const o = s.onboard_log;
  if (o && o.file) {
    const id = encodeURIComponent(s.id);
    td.append(el("a", { href: `/api/sessions/${id}/files/${o.file}` }, o.file), ` ${fmtSize(o.bytes)}`);
    if (!o.complete) td.append(" ", el("span", { class: "quality-bad" }, "incomplete"));
    td.title = o.message;
  } else if (o) {
    td.append(el("span", { class: "quality-bad" }, o.state.replace("_", " ")));
    td.title = o.message;
  }
  if ((!o || !o.complete) && !s.recording_now && live && live.available && !ACTIVE.has(live.state)) {
    const fetch = el("button", { type: "button", class: "fetch-onboard" }, o ? "fetch again" : "fetch");
    fetch.addEventListener("click", () => fetchOnboard(s.id));
    td.append(" ", fetch);
  }
}

async function fetchOnboard(id) {
  try {
    await api(`/api/sessions/${encodeURIComponent(id)}/onboard_log`, { method: "POST", body: {} });
  } catch (err) {
    alert(`Cannot fetch the onboard log: ${err.message}`);
  }
  load();
}

async function onboardStatus() {
  try {
    return await api("/api/onboard_log");
  } catch {
    return null;
  }
}

// While a download runs, its row's cell follows it every second.
async function followProgress(sessions) {
  clearTimeout(progressTimer);
  const live = await onboardStatus();
  for (const s of sessions) {
    const td = tbody.querySelector(`tr[data-id="${CSS.escape(s.id)}"] td.onboard`);
    if (td) onboardCell(td, s, live);
  }
  if (live && ACTIVE.has(live.state)) progressTimer = setTimeout(() => followProgress(sessions), 1000);
  else if (live && live.session && sessions.some((s) => s.id === live.session && !s.onboard_log)) {
    progressTimer = setTimeout(load, 1000); // just ended: its session.json is being written
  }
}

async function load() {
  let sessions;
  try {
    sessions = await api("/api/sessions");
    await refreshSelection();
    $("error").hidden = true;
  } catch (err) {
    $("error").textContent = `Cannot list sessions: ${err.message}`;
    $("error").hidden = false;
    return;
  }
  tbody.replaceChildren();
  $("empty").hidden = sessions.length > 0;
  knownPilots(sessions.filter((s) => s.demonstration).map((s) => s.demonstration.pilot));
  for (const s of sessions) {
    if (selection.ids && !selection.ids.has(s.id)) continue;
    const crashed = s.flags.some((f) => f.kind === "crash");
    const tr = el("tr", { "data-id": s.id, class: crashed ? "crashed" : null });
    // start_utc is in the clock the session chose (the vehicle's GPS when the Pi's was off).
    const start = s.start_utc ? new Date(s.start_utc).toLocaleString() : s.id;
    cell(tr, start).title = s.id;
    cell(tr, s.recording_now ? "recording..." : fmtDuration(s.duration_s), "num");
    cell(tr, s.source);
    cell(tr, fmtSize(s.size_bytes), "num");
    const status = cell(tr, statusText(s), `status status-${s.status}`);
    status.title = s.stop_reason || "";
    if (crashed) status.append(" ", el("span", { class: "crash-mark" }, "CRASHED"));
    qualityCell(tr, s);
    cell(tr, s.task ? `${s.task.id}. ${s.task.name}` : "--", "task");
    const d = s.demonstration;
    cell(tr, d ? (d.kind === "human" ? `${d.pilot} (${d.attempt}/${d.attempts})` : d.kind) : "--", "pilot");
    const bad = s.score && (!s.score.ok || (s.score.result && s.score.result.valid === false));
    cell(tr, scoreText(s), bad ? "quality-bad score" : "score").title = scoreTitle(s);
    cell(tr, s.onboard_log ? "" : "--", "onboard");
    const id = encodeURIComponent(s.id);
    const del = el("button", { type: "button", class: "delete", disabled: s.recording_now }, "delete");
    del.addEventListener("click", () => remove(s.id));
    cell(tr, "").append(
      el("a", { class: "replay", href: `/replay.html?session=${id}` }, "replay"), " ",
      el("a", { class: "analysis", href: `/analysis.html?sessions=${id}` }, "analysis"), " ",
      el("a", { class: "download", href: `/api/sessions/${id}/download` }, "download"), " ",
      del,
    );
    tbody.appendChild(tr);
  }
  followProgress(sessions);
}

onSelection(load);
load();
setInterval(load, 5000);
