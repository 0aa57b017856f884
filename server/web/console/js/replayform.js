// The replay's form: which vehicles (the selected ones ticked first) and the window. The
// window is "the last N minutes" (15, or the shortcut last pressed) up to the moment the
// Replay tab opens, every time it opens, until the person types a time: a window set when
// the page loaded went stale (at 16:09 it still ended at 16:03).

import { h } from "./ui.js";

const $ = (id) => document.getElementById(id);

function toLocalInput(t) {
  const d = new Date(t - new Date(t).getTimezoneOffset() * 60000);
  return d.toISOString().slice(0, 19);
}

function fromLocalInput(value) {
  return new Date(value).getTime(); // a datetime-local value is read as local time
}

export class ReplayForm {
  constructor(ctx) {
    this.ctx = ctx;
    this.minutes = 15;
    this.typed = false; // a time typed or picked: kept as it is
    for (const b of document.querySelectorAll("#replay-form [data-minutes]")) {
      b.addEventListener("click", () => {
        this.minutes = +b.dataset.minutes;
        this.typed = false;
        this.setWindow();
      });
    }
    for (const field of [$("replay-from"), $("replay-to")]) {
      field.addEventListener("input", () => { this.typed = true; });
    }
    this.setWindow();
  }

  /** The Replay tab opens: the vehicles offered again, the window brought up to now
   * unless the person typed it. */
  opened() {
    this.drawChoices();
    if (!this.typed) this.setWindow();
  }

  /** The last ``this.minutes`` minutes, up to now. */
  setWindow() {
    const now = Date.now();
    $("replay-from").value = toLocalInput(now - this.minutes * 60000);
    $("replay-to").value = toLocalInput(now);
  }

  /** The window as typed: {start, end} in ms (NaN when a field is empty). */
  window() {
    return { start: fromLocalInput($("replay-from").value), end: fromLocalInput($("replay-to").value) };
  }

  /** The vehicle checkboxes: the user's ticks kept; a vehicle not offered before is
   * ticked when it is selected, or when nothing is selected (every vehicle). */
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
          : selection.size ? selection.has(v.id) : true,
      }),
      ` ${v.view.name || v.id}`)));
  }

  /** The vehicles ticked. */
  chosen() {
    return [...document.querySelectorAll("#replay-vehicles input:checked")].map((i) => i.value);
  }
}
