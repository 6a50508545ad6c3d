// fpv-station goggles page (/goggles.html): the front camera full screen under the OSD
// (osd.js), for HDMI goggles at 1280x720 or 1920x1080 and phones; no page chrome.
//   F or a tap   fullscreen          B   bottom camera picture-in-picture
//   O            OSD elements menu   S   side-by-side stereo (phone headsets)
// The screen is kept awake (Screen Wake Lock, re-taken when the page is shown again), and
// the flight task's next step (task-panel.js onTaskStep) is an OSD line. The
// picture fills the screen (object-fit: cover in style.css): a 4:3 camera on 16:9
// goggles loses its edges rather than a quarter of the screen to black bars. In stereo each
// eye shows the whole picture at its aspect ratio (a half screen is narrower than any
// camera's frame), and the bottom camera's PiP takes its frames' shape.
import { expose } from "/debug.js";
import { $, el } from "/lib.js";
// osd.js before emergency.js and voice.js: they put their controls in the menu of the OSD
// it mounts when loaded.
import { mountOsd, pageOsd } from "/osd.js";
import { emergencyButtons } from "/emergency.js";
import { nextAction, onTaskStep } from "/task-panel.js";
import { cameras } from "/video.js";
import { voiceControls } from "/voice.js";

function toggleFullscreen() {
  if (document.fullscreenElement) document.exitFullscreen().catch(() => {});
  else document.documentElement.requestFullscreen().catch(() => {});
}

window.addEventListener("keydown", (e) => {
  if (e.ctrlKey || e.metaKey || e.altKey) return;
  const key = e.key.toLowerCase();
  if (key === "f") toggleFullscreen();
  else if (key === "b") $("bottom-view").hidden = !$("bottom-view").hidden;
  else if (key === "o" && pageOsd) pageOsd.toggleMenu();
  else if (key === "s") toggleStereo();
  else return;
  e.preventDefault();
});
$("goggles").addEventListener("click", (e) => {
  if (e.target.closest(".view") && !e.target.closest(".osd-menu, .osd-menu-button")) toggleFullscreen();
});

// Keep the screen on while the page is shown (goggles and phones sleep otherwise).
let wakeLock = null;
async function keepAwake() {
  if (!("wakeLock" in navigator) || document.visibilityState !== "visible" || wakeLock) return;
  try {
    wakeLock = await navigator.wakeLock.request("screen");
    wakeLock.addEventListener("release", () => { wakeLock = null; });
    document.body.dataset.wakeLock = "on";
  } catch (err) {
    document.body.dataset.wakeLock = "refused"; // e.g. not a secure context: http://pi.local
  }
}
document.addEventListener("visibilitychange", keepAwake);
keepAwake();

// Both eyes show it in stereo; the right eye, mounted later, starts with the current one.
let right = null, rightOsd = null; // the right eye's view and OSD, once stereo is on
let taskLine = "";
onTaskStep((step) => {
  taskLine = step ? `next: ${nextAction(step)}` : "";
  for (const osd of [pageOsd, rightOsd]) if (osd) osd.setLine("task", taskLine);
});

// Side-by-side stereo for phone headsets: the same front picture and OSD for each eye.
// The right eye draws the same decoded frames as the left (video.js: one subscription per
// camera and page); it and its OSD stop when stereo is switched off.
function toggleStereo() {
  const on = !document.body.classList.contains("stereo");
  document.body.classList.toggle("stereo", on);
  if (on && !right) {
    right = el("section", { id: "front-view-right", class: "view", "aria-label": "front view, right eye" });
    const canvas = el("canvas", { class: "video-stream", role: "img", "aria-label": "front camera, right eye", width: 4, height: 3 });
    right.append(canvas);
    $("goggles").append(right);
    cameras.addTarget("front", canvas); // drawn from the left eye's frames
    // The same OSD and menu in the right eye (osd.js: one menu state for both eyes).
    rightOsd = mountOsd(right);
    rightOsd.menuBox.append(emergencyButtons(), voiceControls());
    rightOsd.setLine("task", taskLine);
    expose("osdRight", rightOsd);
  }
  rightOsd.setRunning(on); // a hidden eye draws nothing
  right.hidden = !on;
}
