// Toasts: what changes for the person at the console, said for a few seconds. At most
// VISIBLE of them show at once (the newest); the others wait behind a "+N more" that
// opens the log of every message said in this tab, so a burst of stops or alarms never
// covers the map and the action bar on a phone.

import { clock, h, sends } from "./ui.js";

const VISIBLE = 3;
const LOG_KEPT = 100;
const log = []; // {at, message, kind}, newest last

/** A toast; ``action`` ({label, run, sends}) adds a button to it. */
export function toast(message, kind = "info", action = null) {
  const box = document.getElementById("toasts");
  const item = h(`div.toast.${kind}`, { role: kind === "error" ? "alert" : "status" },
    h("span.msg", { title: message }, message));
  if (action) {
    item.append(h("button", { ...(action.sends ? sends(action.sends) : {}), onclick: action.run },
      action.label));
  }
  const remove = () => {
    item.remove();
    arrange(box);
  };
  item.append(h("button.quiet.close", { onclick: remove, "aria-label": "close" }, "×"));
  box.append(item);
  log.push({ at: Date.now(), message, kind });
  if (log.length > LOG_KEPT) log.shift();
  arrange(box);
  setTimeout(remove, kind === "error" || kind === "warn" ? 12000 : 5000);
  return item;
}

/** The newest VISIBLE toasts shown, the rest hidden (each still ends on its own time)
 * and counted on the "+N more" button. */
function arrange(box) {
  const items = [...box.querySelectorAll(".toast")];
  items.forEach((el, i) => { el.hidden = i < items.length - VISIBLE; });
  const hidden = Math.max(0, items.length - VISIBLE);
  let more = box.querySelector(".toast-more");
  if (!hidden) {
    if (more) more.remove();
    return;
  }
  if (!more) {
    more = h("button.toast-more", { type: "button", onclick: openLog });
    box.prepend(more);
  }
  more.textContent = `+${hidden} more`;
  more.setAttribute("aria-label", `${hidden} more messages: open the log`);
}

/** Every message said in this tab, newest first. */
export function openLog() {
  const dialog = document.getElementById("toast-log");
  const list = document.getElementById("toast-log-list");
  list.replaceChildren(...log.slice().reverse().map((m) => h(`li.${m.kind}`, {},
    h("time", {}, clock(m.at)), " ", m.message)));
  if (!dialog.open) dialog.showModal();
}
