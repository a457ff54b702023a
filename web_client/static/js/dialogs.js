// Modal dialogs (help, share link, alignment pictures): open one, Escape or its Close button
// closes it and gives focus back to where it was; Tab stays inside while it is open.
const $ = (id) => document.getElementById(id);

let open = null;  // {box, returnTo}

export function openDialog(id, focus) {
  if (open) closeDialog();
  const box = $(id);
  open = { box, returnTo: document.activeElement };
  box.hidden = false;
  (focus ? $(focus) : box.querySelector("button, input, select, a[href]"))?.focus();
}

export function closeDialog() {
  if (!open) return;
  const { box, returnTo } = open;
  open = null;
  box.hidden = true;
  if (returnTo && document.contains(returnTo)) returnTo.focus();
}

export function dialogOpen() {
  return open !== null;
}

function focusable(box) {
  return [...box.querySelectorAll("button, input, select, a[href], [tabindex='0']")].filter((e) => !e.disabled);
}

export function setUpDialogs(ids) {
  for (const id of ids) {
    const box = $(id);
    box.querySelector("button[id$='-close']").addEventListener("click", closeDialog);
    box.addEventListener("click", (event) => { if (event.target === box) closeDialog(); });  // the backdrop
  }
  window.addEventListener("keydown", (event) => {
    if (!open) return;
    if (event.key === "Escape") {
      closeDialog();
      event.preventDefault();
      event.stopImmediatePropagation();
    } else if (event.key === "Tab") {
      const items = focusable(open.box);
      if (items.length === 0) return;
      const first = items[0], last = items[items.length - 1];
      if (event.shiftKey && document.activeElement === first) { last.focus(); event.preventDefault(); }
      else if (!event.shiftKey && document.activeElement === last) { first.focus(); event.preventDefault(); }
    }
  }, true);
}
