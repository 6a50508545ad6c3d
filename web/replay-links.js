// Sessions page: a "replay" link on every session row (rows carry data-id; the table is
// rebuilt every few seconds, so links are added whenever rows appear).
"use strict";

(() => {
  const tbody = document.querySelector("#sessions tbody");
  if (!tbody) return;

  function addLinks() {
    for (const tr of tbody.querySelectorAll("tr[data-id]")) {
      if (tr.querySelector("a.replay")) continue;
      const a = document.createElement("a");
      a.className = "replay";
      a.href = `/replay.html?session=${encodeURIComponent(tr.dataset.id)}`;
      a.textContent = "replay";
      const actions = tr.lastElementChild || tr;
      actions.prepend(a, " ");
    }
  }

  new MutationObserver(addLinks).observe(tbody, { childList: true });
  addLinks();
})();
