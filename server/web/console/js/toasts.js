// Toasts: what changes for the person at the console, said for a few seconds. At most
// VISIBLE of them show at once (the newest); the others wait behind a "+N more" that
// opens the log of every message said in this tab, so a burst of stops or alarms never
// covers the map and the action bar on a phone.

import { clock, h, sends } from "./ui.js";

const VISIBLE = 3;
const LOG_KEPT = 100;
const log = []; // {at, message, kind}, newest last

/** A toast; ``action`` ({label, run, sends}) adds a button to it. The same message again
 * while its toast is up is counted on it ("×5"), which becomes the newest and starts its
 * time again: five refusals in a row are one toast, not three and "+2 more". */
export function toast(message, kind = "info", action = null, tag = null) {
  const box = document.getElementById("toasts");
  reserve(box);
  const same = [...box.querySelectorAll(".toast")]
    .find((el) => el.dataset.message === message && el.dataset.kind === kind);
  if (same) return again(box, same);
  const item = h(`div.toast.${kind}`, {
    role: kind === "error" ? "alert" : "status",
    dataset: { message, kind, count: 1, ...(tag ? { tag } : {}) },
  }, h("span.msg", { title: message }, message), h("span.count", { hidden: true }));
  if (action) {
    item.append(h("button", { ...(action.sends ? sends(action.sends) : {}), onclick: action.run },
      action.label));
  }
  const remove = () => {
    item.remove();
    arrange(box);
  };
  item.append(h("button.quiet.close", { onclick: remove, "aria-label": "close" }, "×"));
  item.dismiss = remove;
  box.append(item);
  log.push({ at: Date.now(), message, kind, count: 1 });
  if (log.length > LOG_KEPT) log.shift();
  arrange(box);
  item.timer = setTimeout(remove, lasts(kind));
  return item;
}

/** The toasts up with this ``tag`` taken down (what they said no longer holds; the log
 * keeps them). */
export function dismissTagged(tag) {
  for (const el of document.querySelectorAll("#toasts .toast")) {
    if (el.dataset.tag === tag && el.dismiss) el.dismiss();
  }
}

function lasts(kind) {
  return kind === "error" || kind === "warn" ? 12000 : 5000;
}

/** A message said again while its toast is up: counted there, the newest again, its
 * time started again; in the log, its line counted too when it is the newest. */
function again(box, item) {
  const n = +item.dataset.count + 1;
  item.dataset.count = n;
  const count = item.querySelector(".count");
  count.hidden = false;
  count.textContent = `×${n}`;
  count.setAttribute("aria-label", `said ${n} times`);
  box.append(item); // the newest
  clearTimeout(item.timer);
  item.timer = setTimeout(item.dismiss, lasts(item.dataset.kind));
  const last = log[log.length - 1];
  if (last && last.message === item.dataset.message && last.kind === item.dataset.kind) {
    last.count += 1;
    last.at = Date.now();
  } else {
    log.push({ at: Date.now(), message: item.dataset.message, kind: item.dataset.kind, count: 1 });
    if (log.length > LOG_KEPT) log.shift();
  }
  arrange(box);
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

/** The room the toasts take at the bottom of a phone's panes, kept up to date in
 * ``--toasts-reserve`` (their height, the 12 px under them and a 6 px gap; 0 with none):
 * the panes' scrolling area ends above them (console.css), so that no toast covers a
 * button there (one covered the last lease card's Revoke). */
function reserve(box) {
  if (box.reserved) return;
  box.reserved = new ResizeObserver(() => {
    const height = box.offsetHeight;
    document.documentElement.style.setProperty("--toasts-reserve", `${height ? height + 18 : 0}px`);
  });
  box.reserved.observe(box);
}

/** Every message said in this tab, newest first. */
export function openLog() {
  const dialog = document.getElementById("toast-log");
  const list = document.getElementById("toast-log-list");
  list.replaceChildren(...log.slice().reverse().map((m) => h(`li.${m.kind}`, {},
    h("time", {}, clock(m.at)), " ", m.message, m.count > 1 ? ` (×${m.count})` : "")));
  if (!dialog.open) dialog.showModal();
}
