// fpv-station sessions page: select sessions for learning and export them. The form
// writes a selection (task=1,pilot=Ana,kind=human,hover_distance_m<=0.3), the text
// `fpv-station export --select` takes too; the station applies its one rule
// (GET /api/selection, analysis/selection.py): failed trials, by the score stored at the
// disarm, are left out unless "include failed" is ticked, and the page says how many and
// why. The table (sessions.js) then shows only the selected sessions. "Export" starts the
// same export as the command line in a process of the station's own (POST /api/exports);
// the newest export's state is shown with its download once done (GET /api/exports).
import { $, el, api, ApiError } from "/lib.js";

const POLL_MS = 2000;
const listeners = [];
export const selection = { ids: null, text: "" }; // ids: a Set while a selection applies

const task = el("select", { id: "sel-task" }, el("option", { value: "" }, "any task"));
const pilot = el("input", { id: "sel-pilot", type: "text", maxlength: 40, list: "sel-pilots", placeholder: "any pilot" });
const pilots = el("datalist", { id: "sel-pilots" });
const kind = el("select", { id: "sel-kind" }, el("option", { value: "" }, "anyone"),
  el("option", { value: "human" }, "human"), el("option", { value: "scripted" }, "scripted"));
const metric = el("select", { id: "sel-metric" }, el("option", { value: "" }, "no threshold"));
const limit = el("input", { id: "sel-limit", type: "number", step: "any", min: 0, placeholder: "at most" });
const failed = el("input", { id: "sel-failed", type: "checkbox" });
const apply = el("button", { id: "sel-apply", type: "submit" }, "Select");
const clear = el("button", { id: "sel-clear", type: "button" }, "Show all");
const count = el("p", { id: "sel-count", class: "note" });
const format = el("select", { id: "export-format" },
  ...["lerobot", "minari", "mcap"].map((f) => el("option", { value: f }, f)));
const exportButton = el("button", { id: "export-start", type: "button", disabled: true }, "Export selection");
const exportStatus = el("span", { id: "export-status", class: "note" });
const form = el("form", { id: "select-form", class: "select-form" },
  el("label", {}, "Task ", task), el("label", {}, "Pilot ", pilot, pilots),
  el("label", {}, "Flown by ", kind), el("label", {}, "Score ", metric, " \u2264 ", limit),
  el("label", {}, failed, " include failed trials"), apply, clear,
  el("span", { class: "export-controls" }, format, exportButton, exportStatus));
$("selection").append(form, count);

export function onSelection(fn) { listeners.push(fn); }

function terms() {
  const t = [];
  if (task.value) t.push(`task=${task.value}`);
  if (pilot.value.trim()) t.push(`pilot=${pilot.value.trim()}`);
  if (kind.value) t.push(`kind=${kind.value}`);
  if (metric.value && limit.value !== "") t.push(`${metric.value}<=${limit.value}`);
  return t.join(",");
}

let asked = null; // the query of the selection that applies
let askedAt = 0;

async function select(query = `select=${encodeURIComponent(terms())}&include_failed=${failed.checked}`) {
  let reply;
  try {
    reply = await api(`/api/selection?${query}`);
  } catch (err) {
    count.textContent = `Not selected: ${err.message}`;
    return false;
  }
  asked = query;
  askedAt = performance.now();
  selection.ids = new Set(reply.sessions);
  selection.text = reply.select;
  selection.includeFailed = reply.include_failed;
  const out = Object.entries(reply.failed);
  count.textContent = `${reply.sessions.length} session${reply.sessions.length === 1 ? "" : "s"} selected (${reply.select || "every session"})` +
    (out.length ? `; ${out.length} failed trial${out.length > 1 ? "s" : ""} left out` : "");
  count.title = out.map(([id, why]) => `${id}: ${why}`).join("\n");
  exportButton.disabled = reply.sessions.length === 0;
  return true;
}

// The table's reload (sessions.js) takes the selection again: sessions recorded or
// scored since are in it.
export async function refreshSelection() {
  if (selection.ids && performance.now() - askedAt > 1000) await select(asked);
}

form.addEventListener("submit", async (ev) => {
  ev.preventDefault();
  if (await select()) listeners.forEach((fn) => fn());
});
clear.addEventListener("click", () => {
  selection.ids = null;
  count.textContent = "";
  exportButton.disabled = true;
  listeners.forEach((fn) => fn());
});

exportButton.addEventListener("click", async () => {
  try {
    const rec = await api("/api/exports", { method: "POST",
      body: { select: selection.text, include_failed: Boolean(selection.includeFailed), format: format.value } });
    showExport(rec);
  } catch (err) {
    if (err instanceof ApiError) exportStatus.textContent = `Export refused: ${err.message}`;
  }
});

let exportTimer = null;
function showExport(rec) {
  clearTimeout(exportTimer);
  exportStatus.replaceChildren(`export ${rec.id} (${rec.format}, ${rec.sessions.length} sessions): ${rec.state}`);
  exportStatus.dataset.state = rec.state;
  exportStatus.title = rec.message;
  if (rec.state === "done") {
    exportStatus.append(` ${rec.message}, in exports/${rec.id}/ `,
      el("a", { id: "export-download", href: `/api/exports/${encodeURIComponent(rec.id)}/download` }, "download"));
  } else if (rec.state === "running") {
    exportTimer = setTimeout(async () => {
      try { showExport(await api(`/api/exports/${encodeURIComponent(rec.id)}`)); } catch { /* next time */ }
    }, POLL_MS);
  } else {
    exportStatus.append(`: ${rec.message}`);
  }
}

// Shown as the table's rows load: the pilots seen, for the name field's suggestions.
export function knownPilots(names) {
  pilots.replaceChildren(...[...new Set(names)].sort().map((n) => el("option", { value: n })));
}

async function init() {
  try {
    const [tasks, sel, exports] = await Promise.all([api("/api/task"), api("/api/selection"), api("/api/exports")]);
    task.append(...tasks.tasks.map((t) => el("option", { value: String(t.id) }, `${t.id}. ${t.name}`)));
    metric.append(...sel.metrics.map((m) => el("option", { value: m }, m)));
    if (exports.length) showExport(exports[0]);
  } catch {
    // the form still selects by pilot and kind
  }
}

init();
