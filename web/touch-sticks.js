// Two virtual sticks for flying the twin from a phone or tablet (control.js mounts them on
// touch devices while the sticks are on). Mode 2, as on an RC transmitter: the left stick
// is throttle (up/down) and yaw (left/right), the right stick pitch (up = forward) and
// roll. Every axis springs back to centre when the finger lifts except throttle, which
// stays where it was left (a transmitter's throttle gimbal has no spring; in Position mode
// its centre means "hold altitude").
//
// A stick moves with the finger from where it touched down (relative), never to the touch
// point: a thumb landing at the top of the throttle stick does not mean full throttle.
// The range is square, as a gimbal's is, so the corners are reachable: left stick to the
// bottom-right corner (throttle down, yaw right) arms, bottom-left disarms.
//
//   const sticks = mountTouchSticks(parent);
//   sticks.read()    -> {roll, pitch, yaw, throttle} (roll/pitch/yaw -1..1, throttle 0..1)
//   sticks.touched   true once a finger has moved a stick (control.js then reads them)
//   sticks.release() lets go of every finger and centres the sticks (throttle to hold)
//   sticks.show(on)  shows or hides both
// The knob positions are SVG attributes (scripts set no styles).
import { el, svgEl as svg } from "/lib.js";

const clamp = (v) => Math.min(1, Math.max(-1, v));

// One stick: x and y in -1..1 (y up positive); `springY` false keeps y on lift.
function stick(name, springY) {
  const root = svg("svg", { viewBox: "-1.25 -1.25 2.5 2.5", class: `touch-stick touch-stick-${name}`,
    "data-stick": name, role: "slider", "aria-label": `${name} stick` });
  root.append(
    svg("rect", { x: -1, y: -1, width: 2, height: 2, rx: 0.15, class: "ts-gate" }),
    svg("path", { d: "M-1 0H1M0 -1V1", class: "ts-cross" }),
  );
  const knob = svg("circle", { cx: 0, cy: 0, r: 0.28, class: "ts-knob" });
  root.append(knob);
  const s = { root, x: 0, y: 0, pointer: null, start: null };
  s.draw = () => {
    knob.setAttribute("cx", s.x.toFixed(3));
    knob.setAttribute("cy", (-s.y).toFixed(3));
    root.dataset.x = s.x.toFixed(2);
    root.dataset.y = s.y.toFixed(2);
  };
  s.lift = () => {
    s.pointer = null;
    s.x = 0;
    if (springY) s.y = 0;
    s.draw();
  };
  root.addEventListener("pointerdown", (e) => {
    if (s.pointer !== null) return; // one finger per stick
    e.preventDefault();
    s.pointer = e.pointerId;
    s.start = { px: e.clientX, py: e.clientY, x: s.x, y: s.y };
    root.setPointerCapture(e.pointerId);
  });
  root.addEventListener("pointermove", (e) => {
    if (e.pointerId !== s.pointer) return;
    const half = root.getBoundingClientRect().width / 2.5; // viewBox: the gate is 2 of 2.5
    s.x = clamp(s.start.x + (e.clientX - s.start.px) / half);
    s.y = clamp(s.start.y - (e.clientY - s.start.py) / half);
    s.moved = true;
    s.draw();
  });
  for (const type of ["pointerup", "pointercancel", "lostpointercapture"]) {
    root.addEventListener(type, (e) => { if (e.pointerId === s.pointer) s.lift(); });
  }
  s.draw();
  return s;
}

export function mountTouchSticks(parent) {
  const left = stick("left", false), right = stick("right", true);
  const box = el("div", { id: "touch-sticks", class: "touch-sticks", hidden: true });
  box.append(left.root, right.root);
  parent.append(box);
  const api = {
    get touched() { return Boolean(left.moved || right.moved); },
    read() {
      return { roll: right.x, pitch: right.y, yaw: left.x, throttle: (left.y + 1) / 2 };
    },
    release() {
      for (const s of [left, right]) { s.lift(); s.y = 0; s.draw(); }
    },
    // body.sticks-shown: the page's layout keeps its controls clear of them (style.css)
    show(on) {
      box.hidden = !on;
      document.body.classList.toggle("sticks-shown", on);
      if (!on) api.release();
    },
  };
  return api;
}

// A phone or tablet: a touch screen is the main pointer (a touch laptop keeps its keys).
export const touchDevice = () =>
  navigator.maxTouchPoints > 0 && window.matchMedia("(pointer: coarse)").matches;
