// fpv-station pilot page: the flight task. The pilot picks one of the scene's
// tasks (POST /api/task), follows its procedure while the steps light up as the flight
// state reaches them, sees the field from above with the vehicle and this flight's trail,
// and gets the trial's score when the vehicle disarms (the station scores the recorded
// session with the same code as `fpv-station analyze`).
//
// Steps are detected here from the telemetry the page already has (window "fpv:telemetry"
// events of flight-state.js): armed, took off (0.5 m), reached the task's height, held it
// (tasks with a hold time: the time counts only while the height stays within the
// tolerance of the task's, and starts again when it leaves it), passed each obstacle on
// the way (tasks that cross the field), landed and disarmed. The score says whether the
// trial counts (valid: no crash, no obstacle touched, landed on the pad), how far from
// the pad's centre it landed, and which figures are better when lower (all as the
// station's analysis gives them; after a restart, the newest of today's trials). The panel
// sits in the right column above the bottom camera (on a laptop or larger the flight
// state moves to a strip under the front camera), so that the front camera keeps the
// left column's height (the paper's large front view); its procedure, map and score are
// seen whole without scrolling on a laptop, goggles' 1080p and a phone upright, and on a
// phone on its side its essentials beside both cameras (style.css). Positions
// are metres east/north of the scene's home, which is plenty exact over a 60 m field (an
// equirectangular projection).
import { $, el, api, ApiError } from "/lib.js";
import { toast } from "/toast.js";

const TAKEOFF_M = 0.5; // the analysis' airborne height (analysis.tasks.TaskParams)
const HEIGHT_TOL_M = 0.3; // "reached 4 m" when within this of the task's height
const TRAIL_MAX = 3000; // points kept for the map (10 min at 5 Hz GPS)
const M_PER_DEG_LAT = 111_320;

let scene = null; // GET /api/scene
let taskInfo = null; // GET /api/task
let flight = null; // this flight: steps done (indices of stepNames), trail; reset on arming
let lastVersion = -1;
let currentStep = null; // the name of the step the pilot is on (onTaskStep)
const stepListeners = [];
let vehicle = null; // {x, y, heading}: metres east/north of the scene's home

const panel = el("section", { id: "task-panel", class: "task-panel", "aria-label": "flight task" });
const select = el("select", { id: "task-select", title: "Flight task for the next sessions" });
const toggle = el("button", { id: "task-toggle", type: "button", title: "Show or hide the task panel" }, "Task");
const body = el("div", { id: "task-body" });
const procedure = el("ol", { id: "task-procedure", class: "procedure" });
const steps = el("ol", { id: "task-steps", class: "steps" });
const map = el("canvas", { id: "task-map", width: 320, height: 200, "aria-label": "top-view map" });
const score = el("div", { id: "task-score", class: "score" });
// The plan (what to fly) across, the map and the steps with the score under it, in the
// right column under the flight state (style.css places them per screen); on the goggles
// page, unseen, in #side.
const plan = el("div", { class: "task-plan" }, el("div", { class: "task-head" }, toggle, select), procedure);
const result = el("div", { class: "task-result" }, steps, score);
body.append(map, result);
panel.append(plan, body);
if ($("main-col")) $("flight-state").after(panel);
else $("side").prepend(panel);

toggle.addEventListener("click", () => {
  body.hidden = procedure.hidden = !body.hidden;
  localStorage.setItem("fpv.task.hidden", body.hidden ? "1" : "");
});
body.hidden = procedure.hidden = localStorage.getItem("fpv.task.hidden") === "1";

select.addEventListener("change", async () => {
  const id = select.value === "" ? null : Number(select.value);
  try {
    taskInfo = await api("/api/task", { method: "POST", body: { task_id: id } });
  } catch (err) {
    if (err instanceof ApiError) toast(`Task not chosen: ${err.message}`, { bad: true });
  }
  render();
});

async function load() {
  try {
    [scene, taskInfo] = await Promise.all([api("/api/scene"), api("/api/task")]);
  } catch (err) {
    setTimeout(load, 2000);
    return;
  }
  select.replaceChildren(
    el("option", { value: "" }, "No task"),
    ...taskInfo.tasks.map((t) => el("option", { value: String(t.id) }, `${t.id}. ${t.name}`)),
  );
  render();
}

// -- the flight's steps ----------------------------------------------------------------

// Follow the step the pilot is on (null: no task): `listener` is called at once with the
// current step when there is one, then on every change. A page may run this module as its
// own script before the modules that follow it are loaded (goggles.html), so a first step
// found meanwhile must not be lost to them, as a one-off event would be.
export function onTaskStep(listener) {
  stepListeners.push(listener);
  if (currentStep !== null) listener(currentStep);
}

// The panel names each step as done ("Armed", "Reached 4 m"); the goggles' OSD line and the
// voice callouts say what to do next ("arm", "climb to 4 m").
const NEXT = [[/^Armed$/, "arm"], [/^Took off$/, "take off"], [/^Reached (.+)$/, "climb to $1"],
  [/^Held (.+)$/, "hold $1"], [/^Passed (.+)$/, "pass $1"], [/^Landed$/, "land"], [/^Disarmed$/, "disarm"]];
export function nextAction(step) {
  const found = NEXT.find(([done]) => done.test(step));
  return found ? step.replace(found[0], found[1]) : step;
}

function stepNames(task) {
  if (!task) return [];
  const names = ["Armed", "Took off", `Reached ${task.altitude_m} m`];
  if (task.hold_s > 0) names.push(`Held ${task.hold_s} s`);
  if (task.start_pad !== task.end_pad && scene) {
    for (const o of sortedObstacles(task)) names.push(`Passed ${o.name}`);
  }
  names.push("Landed", "Disarmed");
  return names;
}

function sortedObstacles(task) {
  // Along the start-to-end line, in the order the vehicle meets them.
  const a = pad(task.start_pad), b = pad(task.end_pad);
  if (!a || !b) return [];
  const ux = b.x_m - a.x_m, uy = b.y_m - a.y_m;
  const along = (p) => (p.x_m - a.x_m) * ux + (p.y_m - a.y_m) * uy;
  return scene.obstacles.filter((o) => along(o) > 0 && along(o) < along(b)).sort((p, q) => along(p) - along(q));
}

const pad = (name) => scene && scene.pads.find((p) => p.name === name);

function toField(lat, lon) {
  const h = scene.home;
  return {
    x: (lon - h.lon_deg) * M_PER_DEG_LAT * Math.cos((h.lat_deg * Math.PI) / 180),
    y: (lat - h.lat_deg) * M_PER_DEG_LAT,
  };
}

function track(msg) {
  const s = msg.state;
  const armed = s.heartbeat.armed;
  const alt = s.altitude.relative_alt_m;
  const t = msg.t_server_mono;
  const fix = s.global_position.lat_deg != null ? s.global_position : s.gps;
  if (scene && fix.lat_deg != null) {
    vehicle = { ...toField(fix.lat_deg, fix.lon_deg), heading: s.vfr_hud.heading_deg };
  }
  if (armed && (!flight || flight.ended)) {
    flight = { done: new Set([0]), trail: [], heldSince: null, ended: false, pos: null };
  }
  if (!flight) return;
  if (vehicle && armed) {
    const last = flight.trail[flight.trail.length - 1];
    if (!last || Math.hypot(vehicle.x - last.x, vehicle.y - last.y) > 0.05) {
      flight.trail.push({ x: vehicle.x, y: vehicle.y });
    }
    if (flight.trail.length > TRAIL_MAX) flight.trail.shift();
    flight.pos = vehicle;
  }
  const task = taskInfo && taskInfo.selected;
  if (!task) return;
  // Step indices as stepNames lists them, in any order the pilot flies them (an aborted
  // trial leaves its skipped steps open). An event counts once it happened (armed, took
  // off, reached the height, held it for hold_s); a place holds only while the vehicle is
  // there: past an obstacle, on the ground (a touch-and-go is not a landing).
  const done = flight.done;
  const airborne = alt != null && alt > TAKEOFF_M;
  let i = 1;
  if (armed && airborne) done.add(i);
  const tookOff = done.has(1);
  i += 1;
  if (tookOff && alt != null && alt >= task.altitude_m - HEIGHT_TOL_M) done.add(i);
  i += 1;
  if (task.hold_s > 0) {
    // Held: the height within the tolerance for hold_s without a break.
    const atHeight = tookOff && armed && alt != null && Math.abs(alt - task.altitude_m) <= HEIGHT_TOL_M;
    if (!atHeight) flight.heldSince = null;
    else if (flight.heldSince === null) flight.heldSince = t;
    else if (t - flight.heldSince >= task.hold_s) done.add(i);
    i += 1;
  }
  if (task.start_pad !== task.end_pad && scene) {
    const a = pad(task.start_pad), b = pad(task.end_pad);
    for (const o of sortedObstacles(task)) {
      if (tookOff && flight.pos && a && b) {
        const ux = b.x_m - a.x_m, uy = b.y_m - a.y_m, n = Math.hypot(ux, uy);
        const along = ((flight.pos.x - o.x_m) * ux + (flight.pos.y - o.y_m) * uy) / n;
        if (along > o.width_m / 2) done.add(i);
        else done.delete(i);
      }
      i += 1;
    }
  }
  if (tookOff && alt != null) {
    if (!airborne) done.add(i); // back on the ground
    else done.delete(i);
  }
  i += 1;
  if (!armed) {
    done.add(i);
    flight.ended = true;
    pollScore();
  }
}

// -- drawing -----------------------------------------------------------------------------

function render() {
  const task = taskInfo && taskInfo.selected;
  select.value = task ? String(task.id) : "";
  procedure.replaceChildren(...(task ? task.procedure.map((line) => el("li", {}, line)) : []));
  const names = stepNames(task);
  const done = flight && task ? flight.done : new Set();
  const current = names.findIndex((_, i) => !done.has(i));
  // The current step for other modules (the goggles' OSD line): null without a task.
  const step = task && current >= 0 ? names[current] : null;
  steps.replaceChildren(
    ...names.map((name, i) =>
      el("li", { class: done.has(i) ? "done" : i === current ? "current" : null, "data-step": String(i) }, name),
    ),
  );
  if (step !== currentStep) {
    currentStep = step;
    for (const listener of stepListeners) listener(step);
  }
  drawMap();
  renderScore();
}

function drawMap() {
  const ctx = map.getContext("2d");
  const W = map.width, H = map.height;
  ctx.fillStyle = "#1d2b1f";
  ctx.fillRect(0, 0, W, H);
  if (!scene) return;
  const [sx, sy] = scene.size_m;
  const scale = Math.min((W - 10) / sx, (H - 10) / sy);
  const px = (x, y) => [W / 2 + x * scale, H / 2 - y * scale];
  const rgb = (c) => `rgb(${c[0]},${c[1]},${c[2]})`;
  if (scene.is_field) {
    ctx.strokeStyle = "#6b8f6b";
    ctx.strokeRect(W / 2 - (sx / 2) * scale, H / 2 - (sy / 2) * scale, sx * scale, sy * scale);
    for (const p of scene.pads) {
      const [x, y] = px(p.x_m, p.y_m), s = Math.max(p.size_m * scale, 4);
      ctx.fillStyle = rgb(p.rgb);
      ctx.fillRect(x - s / 2, y - s / 2, s, s);
    }
    for (const o of scene.obstacles) {
      const [x, y] = px(o.x_m - o.width_m / 2, o.y_m + o.depth_m / 2);
      ctx.fillStyle = rgb(o.rgb);
      ctx.fillRect(x, y, Math.max(o.width_m * scale, 3), Math.max(o.depth_m * scale, 3));
    }
    const task = taskInfo && taskInfo.selected;
    const a = task && pad(task.start_pad), b = task && pad(task.end_pad);
    if (a && b && a !== b) { // the reference line: start pad to end pad (+x of the analysis)
      ctx.strokeStyle = "#e0e0e0";
      ctx.setLineDash([4, 4]);
      ctx.beginPath();
      ctx.moveTo(...px(a.x_m, a.y_m));
      ctx.lineTo(...px(b.x_m, b.y_m));
      ctx.stroke();
      ctx.setLineDash([]);
    }
  } else { // no scene file for this field: the home point only
    ctx.fillStyle = "#e0e0e0";
    ctx.fillRect(W / 2 - 2, H / 2 - 2, 4, 4);
  }
  if (flight && flight.trail.length > 1) {
    ctx.strokeStyle = "#ffd24a";
    ctx.beginPath();
    flight.trail.forEach((p, i) => (i ? ctx.lineTo(...px(p.x, p.y)) : ctx.moveTo(...px(p.x, p.y))));
    ctx.stroke();
  }
  if (vehicle) {
    const [x, y] = px(vehicle.x, vehicle.y);
    const hd = ((vehicle.heading || 0) * Math.PI) / 180; // compass: 0 north, clockwise
    ctx.fillStyle = "#ff4040";
    ctx.beginPath();
    ctx.moveTo(x + 8 * Math.sin(hd), y - 8 * Math.cos(hd));
    ctx.lineTo(x + 4 * Math.sin(hd + 2.4), y - 4 * Math.cos(hd + 2.4));
    ctx.lineTo(x + 4 * Math.sin(hd - 2.4), y - 4 * Math.cos(hd - 2.4));
    ctx.fill();
    map.dataset.vehicle = `${vehicle.x.toFixed(1)},${vehicle.y.toFixed(1)}`;
  }
}

function fmt(v, unit) {
  return v == null ? "--" : `${v.toFixed(unit === "s" ? 1 : 3)} ${unit}`;
}

// The figures of a scored trial, as analysis.tasks.TaskResult names them; a field the
// station lists as lower-is-better (GET /api/task lower_is_better) carries a "\u2193".
function figures(task, r) {
  const rows = task.analysis === "hover"
    ? [["hover_distance_m", "hover", "m"]]
    : [["lateral_deviation_m", "lateral dev.", "m"]];
  rows.push(["height_deviation_m", "height dev.", "m"]);
  if (r.landing_accuracy_m != null) rows.push(["landing_accuracy_m", `landed from pad ${r.landing_pad}`, "m"]);
  if (r.obstacle_contacts != null) rows.push(["obstacle_contacts", "obstacle contacts", ""]);
  rows.push(["trial_time_s", "time", "s"]);
  const lower = new Set(taskInfo.lower_is_better || []);
  return rows.map(([key, name, unit]) => {
    const v = r[key];
    const text = unit ? fmt(v, unit) : String(v);
    return el("span", { class: "figure", "data-field": key, title: lower.has(key) ? "lower is better" : null },
      `${name} ${text}${lower.has(key) ? " \u2193" : ""}`);
  });
}

function renderScore() {
  const task = taskInfo && taskInfo.selected;
  if (!task) { score.replaceChildren(); return; }
  const rows = [];
  if (taskInfo.scoring) rows.push(el("p", { class: "note" }, "Scoring the flight just recorded..."));
  const last = taskInfo.last_score;
  if (last && last.task === task.analysis) {
    if (last.ok) {
      const r = last.result;
      const valid = r.valid !== false;
      const parts = figures(task, r).flatMap((f, i) => (i ? [", ", f] : [f]));
      rows.push(el("p", { id: "task-result", class: valid ? "result" : "result bad", "data-valid": String(valid) },
        el("b", { class: "verdict" }, valid ? "Valid" : "Invalid"), " trial: ", ...parts));
      if (!valid) {
        rows.push(el("p", { id: "task-invalid", class: "result bad" }, `Does not count: ${r.invalid_reasons.join("; ")}`));
      }
    } else {
      rows.push(el("p", { id: "task-result", class: "result bad" }, `Last trial not scored: ${last.reason}`));
    }
  }
  // One line of notes: which way is better, the paper's figures, today's attempts (folded).
  const notes = [];
  if (last && last.ok && last.task === task.analysis) notes.push("\u2193 lower is better. ");
  const paper = taskInfo.paper;
  if (paper) {
    const key = task.analysis === "hover" ? "hover_distance_m" : "lateral_deviation_m";
    const name = task.analysis === "hover" ? "hover" : "lateral dev.";
    notes.push(`Paper: ${name} ${fmt(paper.physical[key], "m")} physical, ${fmt(paper.twin[key], "m")} twin; ` +
      `time ${fmt(paper.physical.trial_time_s, "s")} / ${fmt(paper.twin.trial_time_s, "s")}`);
  }
  if (notes.length) rows.push(el("p", { class: "note" }, ...notes));
  if (taskInfo.attempts.length) {
    // Today's attempts fold away: the newest trial's score above is what must be seen.
    const list = el("ul", { id: "task-attempts", class: "attempts" },
      ...taskInfo.attempts.map((a) => el("li", {}, `${a.start_utc.slice(11, 19)} ` +
        (a.score.ok ? (task.analysis === "hover" ? fmt(a.score.result.hover_distance_m, "m") : fmt(a.score.result.lateral_deviation_m, "m")) + `, ${fmt(a.score.result.trial_time_s, "s")}` +
          (a.score.result.valid === false ? " (invalid)" : "") : `not scored`))));
    const open = score.querySelector("details.attempts-box");
    rows.push(el("details", { class: "attempts-box", open: Boolean(open && open.open) },
      el("summary", {}, `Today: ${taskInfo.attempts.length} attempt${taskInfo.attempts.length > 1 ? "s" : ""}`), list));
  }
  score.replaceChildren(...rows);
}

let polling = false;
async function pollScore() {
  if (polling) return;
  polling = true;
  const before = taskInfo && taskInfo.last_session;
  for (let i = 0; i < 60; i++) { // the recorder's tail, then the analysis: up to a minute
    await new Promise((r) => setTimeout(r, 1000));
    try {
      taskInfo = await api("/api/task");
    } catch (err) {
      continue;
    }
    render();
    if (taskInfo.last_session !== before && !taskInfo.scoring) break;
  }
  polling = false;
}

let drawPending = false;
window.addEventListener("fpv:telemetry", (e) => {
  const msg = e.detail;
  if (msg.version === lastVersion) return;
  lastVersion = msg.version;
  track(msg);
  if (!drawPending) {
    drawPending = true;
    requestAnimationFrame(() => { drawPending = false; render(); });
  }
});

load();
