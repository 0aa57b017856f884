// Small pieces the panels share: building elements, times, toasts (toasts.js), the
// confirmation.

/** h("button.primary", {onclick}, "text", child...): an element. */
export function h(spec, props = {}, ...children) {
  const [tag, ...classes] = spec.split(".");
  const el = document.createElement(tag || "div");
  if (classes.length) el.className = classes.join(" ");
  for (const [k, v] of Object.entries(props || {})) {
    if (v === undefined || v === null || v === false) continue;
    if (k.startsWith("on")) el.addEventListener(k.slice(2), v);
    else if (k === "dataset") Object.assign(el.dataset, v);
    else if (k in el && typeof v !== "string") el[k] = v;
    else el.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children.flat()) {
    if (c === null || c === undefined || c === false) continue;
    el.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return el;
}

export function clock(ts) {
  const t = typeof ts === "number" ? ts : Date.parse(ts);
  if (!Number.isFinite(t)) return "–";
  return new Date(t).toLocaleTimeString([], { hour12: false });
}

/** A local time as "2026-11-26 14:05:00": 24-hour, year first, whatever the browser's
 * language (an English one wrote "11/26/2026, 2:05:00 PM"). The replay's window is typed
 * in this form (replayform.js). */
export function localStamp(t) {
  const d = new Date(t);
  const two = (n) => String(n).padStart(2, "0");
  return `${String(d.getFullYear()).padStart(4, "0")}-${two(d.getMonth() + 1)}-${two(d.getDate())} ` +
    `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())}`;
}

/** A full date with its zone: "2026-11-26 14:05:00 GMT+1". */
export function dateTime(ts) {
  const t = typeof ts === "number" ? ts : Date.parse(ts);
  if (!Number.isFinite(t)) return "–";
  const zone = new Intl.DateTimeFormat([], { timeZoneName: "short" }).formatToParts(new Date(t))
    .find((p) => p.type === "timeZoneName");
  return `${localStamp(t)}${zone ? ` ${zone.value}` : ""}`;
}

/** The zone this browser shows times in: "UTC+01:00 (Europe/Zagreb)", or "UTC". */
export function zoneText(at = new Date()) {
  const minutes = -at.getTimezoneOffset();
  const name = Intl.DateTimeFormat().resolvedOptions().timeZone || "";
  if (minutes === 0 && (!name || name === "UTC" || name === "Etc/UTC")) return "UTC";
  const sign = minutes < 0 ? "-" : "+";
  const hh = String(Math.floor(Math.abs(minutes) / 60)).padStart(2, "0");
  const mm = String(Math.abs(minutes) % 60).padStart(2, "0");
  return `UTC${sign}${hh}:${mm}${name ? ` (${name})` : ""}`;
}

/** "1 vehicle", "3 vehicles" (not "3 vehicle(s)"). */
export function counted(n, what) {
  return `${n} ${what}${n === 1 ? "" : "s"}`;
}

/** "4 s ago", "3 min ago", "2 h ago". */
export function ago(t, now = Date.now()) {
  if (!Number.isFinite(t)) return "never";
  const s = Math.max(0, Math.round((now - t) / 1000));
  if (s < 90) return `${s} s ago`;
  if (s < 5400) return `${Math.round(s / 60)} min ago`;
  return `${Math.round(s / 3600)} h ago`;
}

/** "in 14 min", "in 1 h 05 min". */
export function until(ts, now = Date.now()) {
  const t = Date.parse(ts);
  if (!Number.isFinite(t)) return "";
  const s = Math.round((t - now) / 1000);
  if (s <= 0) return "ended";
  if (s < 90) return `in ${s} s`;
  const m = Math.round(s / 60);
  if (m < 90) return `in ${m} min`;
  return `in ${Math.floor(m / 60)} h ${String(m % 60).padStart(2, "0")} min`;
}

// Calls to the server in flight, by what they do ("grant/<instance>", "stop", ...).
const inFlight = new Set();

/**
 * Run ``call`` (a call to the server, with whatever it asks first) unless one for the same
 * ``key`` is already in flight: a double click or a second tap sends nothing twice.
 * Meanwhile every button marked for that key (``sends(key)``, or ``data-sends`` in the
 * page) is disabled, and so is one drawn then (the panels are drawn again on every change).
 */
export async function sending(key, call) {
  if (inFlight.has(key)) return undefined;
  inFlight.add(key);
  markSending(key, true);
  try {
    return await call();
  } finally {
    inFlight.delete(key);
    markSending(key, false);
  }
}

/** The props of a button whose click makes ``key``'s call (``h("button", {...sends(key)})``). */
export function sends(key) {
  return { dataset: { sends: key }, disabled: inFlight.has(key) };
}

function markSending(key, busy) {
  for (const b of document.querySelectorAll("[data-sends]")) {
    if (b.dataset.sends === key) b.disabled = busy;
  }
}

export { toast } from "./toasts.js";

/**
 * A number as a person types it: digits with at most one decimal point, or a decimal
 * comma read as one ("0,3" is 0.3, whatever the browser's language). Anything else (an
 * exponent, a second separator, a unit, "Infinity") is not a number here: null.
 */
export function parseDecimal(text) {
  const s = String(text ?? "").trim();
  if (!/^[+-]?(\d+([.,]\d*)?|[.,]\d+)$/.test(s)) return null;
  const x = Number(s.replace(",", "."));
  return Number.isFinite(x) ? x : null;
}

/**
 * A numeric field read for a command (``type="text" inputmode="decimal"``, its range in
 * ``data-min`` and ``data-max``): ``{ value }`` (``value`` undefined when it is empty and
 * ``optional``), or ``{ error }`` saying what it takes, and nothing may be sent then.
 * ``what`` names it, ``unit`` its unit, ``optional`` what an empty field means.
 */
export function readNumber(field, { what, unit, optional = null }) {
  const min = +field.dataset.min;
  const max = +field.dataset.max;
  const typed = field.value.trim();
  if (typed === "" && optional) return { value: undefined };
  const takes = `${what} is ${min} to ${max} ${unit}${optional ? `, or empty for ${optional}` : ""}`;
  const value = parseDecimal(typed);
  if (value === null) {
    return { error: `${takes}: "${typed}" is not a plain number (a decimal point or comma); nothing sent` };
  }
  if (value < min || value > max) return { error: `${takes} (not ${value}); nothing sent` };
  return { value };
}

const ARM_MS = 800;

// A click meant for a dialog must not reach the map under it: a double click on a
// confirmation's button ("Stop it") sent its second click to the map, where an armed Go to
// sent the boat there (before the stop), and zoomed the map in. The rest of a double click
// that closed a dialog (its close event comes after the click) is dropped; a new click on
// the map is the map's.
const AFTER_DIALOG_MS = 600;
let dialogEndedAt = 0;
for (const kind of ["submit", "close", "cancel"]) {
  document.addEventListener(kind, (e) => {
    if (e.target.closest && e.target.closest("dialog")) dialogEndedAt = Date.now();
  }, true);
}
for (const kind of ["pointerdown", "mousedown", "click", "dblclick"]) {
  document.addEventListener(kind, (e) => {
    const onMap = e.target.closest && e.target.closest("#map");
    if (!onMap) return;
    const rest = e.type === "dblclick" || e.detail > 1; // the second click of a double one
    if (document.querySelector("dialog[open]") || (rest && Date.now() - dialogEndedAt < AFTER_DIALOG_MS)) {
      e.stopPropagation();
      e.preventDefault();
    }
  }, true);
}

/**
 * A confirmation that a stray tap cannot give: a modal whose confirming button sits
 * away from the button that opened it, is disabled for the first moments (a double
 * click or a second tap lands on nothing) and is not the default (Enter and Escape
 * cancel). Resolves true only when that button is pressed.
 */
export function confirmAction({ title, text, confirm }) {
  const dialog = document.getElementById("confirm");
  const ok = document.getElementById("confirm-ok");
  const cancel = document.getElementById("confirm-cancel");
  document.getElementById("confirm-title").textContent = title;
  document.getElementById("confirm-text").textContent = text;
  ok.textContent = confirm;
  ok.disabled = true;
  ok.classList.add("arming");
  dialog.returnValue = "";
  return new Promise((resolve) => {
    const armed = setTimeout(() => {
      ok.disabled = false;
      ok.classList.remove("arming");
    }, ARM_MS);
    dialog.addEventListener(
      "close",
      () => {
        clearTimeout(armed);
        ok.disabled = true;
        resolve(dialog.returnValue === "ok");
      },
      { once: true },
    );
    dialog.showModal();
    cancel.focus();
  });
}

/** Metres between two {lat, lon} points on the sphere (haversine; the mean radius). */
export function metresBetween(a, b) {
  const rad = Math.PI / 180;
  const dLat = (b.lat - a.lat) * rad;
  const dLon = (b.lon - a.lon) * rad;
  const h = Math.sin(dLat / 2) ** 2
    + Math.cos(a.lat * rad) * Math.cos(b.lat * rad) * Math.sin(dLon / 2) ** 2;
  return 2 * 6371008.8 * Math.asin(Math.min(1, Math.sqrt(h)));
}
