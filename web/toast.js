// fpv-station: one short message over any page, newest wins: a command's result, a
// refusal and why. role=status, so a screen reader says it too.
//
//   import { toast } from "/toast.js";
//   toast("land: accepted");                 // shown 3 s
//   toast("arm refused: ...", { bad: true }); // red, shown 8 s
import { el } from "/lib.js";

let box = null;
let timer = null;

export function toast(text, { bad = false, ms = bad ? 8000 : 3000 } = {}) {
  if (!box) {
    box = el("div", { id: "toast", class: "toast", role: "status", hidden: true });
    document.body.append(box);
  }
  box.textContent = text;
  box.classList.toggle("ok", !bad);
  box.hidden = false;
  clearTimeout(timer);
  timer = setTimeout(() => { box.hidden = true; }, ms);
}
