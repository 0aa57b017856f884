// The replay's form: which vehicles (the selected ones ticked, each time the tab opens
// after the selection changed) and the window. The
// window is "the last N minutes" (15, or the shortcut last pressed) up to now: shown as
// of the moment the Replay tab opens, every time it opens, and taken up to the moment the
// replay is asked, until the person types a time (a window set when the page loaded went
// stale: at 16:09 it still ended at 16:03).
//
// The window's two times are text in one form, "2026-11-26 14:05:00": 24-hour and local,
// whatever the browser's language (a datetime-local picker in an English browser showed
// "02:05:00 PM"). Each is read here, refused in words when it is not such a time, and
// written back in that form once typed; Up and Down step the part under the caret.
//
// Once a replay has been read, the form stays as it asked (its vehicles and its window)
// while the answer (the summary, the events, Export) is shown under it: opening the tab
// again moves nothing on. The person changing the form (a shortcut, a time typed, a box
// ticked) takes the answer away, which no longer belongs to it: after Back to live the
// window had moved on under the old window's summary and export.

import { h, localStamp } from "./ui.js";

const $ = (id) => document.getElementById(id);

export const STAMP_EXAMPLE = "2026-11-26 14:05:00";
const STAMP = /^(\d{4})-(\d{1,2})-(\d{1,2})(?:T| +)(\d{1,2}):(\d{2})(?::(\d{2}))?$/;
// where each part of "2026-11-26 14:05:00" ends (the caret at or before it: that part)
const PARTS = [[4, "FullYear"], [7, "Month"], [10, "Date"], [13, "Hours"], [16, "Minutes"], [19, "Seconds"]];

/** A time typed in the window's form, as local time: ``{t}`` (ms), or ``{error}`` saying
 * what is wrong with it. Seconds may be left out; a "T" may stand for the space. */
export function readStamp(text) {
  const typed = String(text || "").trim();
  const how = `write it as ${STAMP_EXAMPLE} (24-hour, local time)`;
  if (!typed) return { error: `empty: ${how}` };
  const m = STAMP.exec(typed);
  if (!m) return { error: `“${typed}” is not a time this form reads: ${how}` };
  const [y, mo, d, hh, mi, ss] = m.slice(1).map((x) => Number(x || 0));
  if (mo < 1 || mo > 12) return { error: `“${typed}”: no month ${mo}` };
  const days = new Date(y, mo, 0).getDate();
  if (d < 1 || d > days) return { error: `“${typed}”: that month has days 1 to ${days}` };
  if (hh > 23 || mi > 59 || ss > 59) return { error: `“${typed}”: not a time of day (00:00:00 to 23:59:59)` };
  const t = new Date(y, mo - 1, d, hh, mi, ss).getTime();
  const back = new Date(t);
  if (back.getHours() !== hh || back.getMinutes() !== mi) { // skipped when the clocks went forward
    return { error: `“${typed}”: there is no such time here (the clocks went forward then)` };
  }
  return { t };
}

export class ReplayForm {
  constructor(ctx) {
    this.ctx = ctx;
    this.minutes = 15;
    this.ticksFor = ""; // the selection the boxes were last ticked for (none: every vehicle)
    this.typed = false; // a time typed: kept as it is
    this.held = false; // the form as a replay read it, its answer shown: kept as it is
    this.onChange = () => {}; // the person changed the form that was held
    for (const b of document.querySelectorAll("#replay-form [data-minutes]")) {
      b.addEventListener("click", () => {
        this.minutes = +b.dataset.minutes;
        this.typed = false;
        this.setWindow();
        this.changed();
      });
    }
    for (const field of this.fields()) {
      field.addEventListener("input", () => {
        this.typed = true;
        this.changed();
      });
      field.addEventListener("change", () => this.check(field, true));
      field.addEventListener("keydown", (e) => this.step(e, field));
    }
    $("replay-vehicles").addEventListener("change", () => this.changed());
    this.setWindow();
  }

  /** A replay was read as the form asks: it stays so (the tab opening again moves nothing
   * on) until the person changes it. ``on`` false: nothing read is shown any more. */
  hold(on = true) {
    this.held = on;
  }

  /** The person changed the form: what was read for it before is not its answer. */
  changed() {
    if (!this.held) return;
    this.held = false;
    this.onChange();
  }

  fields() {
    return [$("replay-from"), $("replay-to")];
  }

  /** The Replay tab opens: the vehicles offered again, the window brought up to now
   * unless the person typed it. */
  opened() {
    this.drawChoices();
    if (this.held) return; // as the replay shown under it read it
    const selected = [...this.ctx.selection].sort().join(" ");
    if (selected !== this.ticksFor) this.tickSelection(); // it changed since: ticked anew
    if (!this.typed) this.setWindow();
  }

  /** The selected vehicles ticked (every one when none is): the boxes follow the
   * selection each time the tab opens after it changed; ticks made by hand meanwhile stay
   * while it does not. */
  tickSelection() {
    const selection = this.ctx.selection;
    for (const box of $("replay-vehicles").querySelectorAll("input")) {
      box.checked = selection.size ? selection.has(box.value) : true;
    }
    this.ticksFor = [...selection].sort().join(" ");
  }

  /** The last ``this.minutes`` minutes, up to ``now``. */
  setWindow(now = Date.now()) {
    $("replay-from").value = localStamp(now - this.minutes * 60000);
    $("replay-to").value = localStamp(now);
    for (const field of this.fields()) this.check(field, false);
  }

  /** One field read: marked when it is not a time, written back in the form when it is
   * (``tidy``: "2026-11-26 9:05" reads "2026-11-26 09:05:00"). Its time, or an error. */
  check(field, tidy) {
    const got = readStamp(field.value);
    field.setAttribute("aria-invalid", got.error ? "true" : "false");
    field.title = got.error || "";
    if (tidy && got.t !== undefined && field.value !== localStamp(got.t)) field.value = localStamp(got.t);
    return got;
  }

  /** Up or Down: the part under the caret (year to second) one more or one less, as a
   * time picker did; the caret stays in that part. */
  step(e, field) {
    if ((e.key !== "ArrowUp" && e.key !== "ArrowDown") || e.altKey || e.ctrlKey || e.metaKey) return;
    const got = readStamp(field.value);
    if (got.t === undefined) return; // not a time: nothing to step (the message says why)
    e.preventDefault();
    const caret = field.selectionStart ?? field.value.length;
    field.value = localStamp(got.t); // the parts where PARTS says
    const [, unit] = PARTS.find(([end]) => caret <= end) || PARTS[PARTS.length - 1];
    const d = new Date(got.t);
    d[`set${unit}`](d[`get${unit}`]() + (e.key === "ArrowUp" ? 1 : -1));
    field.value = localStamp(d.getTime());
    field.setSelectionRange(caret, caret);
    this.typed = true;
    this.check(field, false);
    this.changed();
  }

  /** The window asked: ``{start, end}`` in ms, or ``{error}`` naming the field. Unless a
   * time was typed, "the last N minutes" up to this moment, to the millisecond (the form
   * shows whole seconds: the window it held ended up to a second before its replay was
   * asked, and left out what happened since the tab opened). */
  window() {
    if (!this.typed) {
      const now = Date.now();
      this.setWindow(now);
      return { start: now - this.minutes * 60000, end: now };
    }
    const from = this.check($("replay-from"), true);
    const to = this.check($("replay-to"), true);
    if (from.error) return { error: `from: ${from.error}` };
    if (to.error) return { error: `to: ${to.error}` };
    return { start: from.t, end: to.t };
  }

  /** The vehicle checkboxes: the user's ticks kept; a vehicle not offered before is
   * ticked when it is selected, or when nothing is selected (every vehicle), but not while
   * the form is held (the replay shown did not read it). */
  drawChoices() {
    const box = $("replay-vehicles");
    const offered = new Map(
      [...box.querySelectorAll("input")].map((i) => [i.value, i.checked]),
    );
    const selection = this.ctx.selection;
    const vehicles = [...this.ctx.fleet.vehicles.values()].sort((a, b) => (a.id < b.id ? -1 : 1));
    box.replaceChildren(...vehicles.map((v) => h("label", {},
      h("input", {
        type: "checkbox", name: "vehicle", value: v.id,
        checked: offered.has(v.id) ? offered.get(v.id)
          : this.held ? false : selection.size ? selection.has(v.id) : true,
      }),
      ` ${v.view.name || v.id}`)));
  }

  /** The vehicles ticked. */
  chosen() {
    return [...document.querySelectorAll("#replay-vehicles input:checked")].map((i) => i.value);
  }
}
