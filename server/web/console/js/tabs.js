// The tabs (Fleet, Vehicle, Control, Replay; on a phone the Map too): which one shows,
// what each reads again when it opens, and the rest of a multiple click dropped when it
// lands in the pane its first click has just shown.

const $ = (id) => document.getElementById(id);
export const PHONE = window.matchMedia("(max-width: 760px)"); // one pane at a time
const SETTLE_MS = 1000; // after a tab switch, how long the rest of its multiple click is dropped

export class Tabs {
  constructor(ctx) {
    this.ctx = ctx;
    for (const b of document.querySelectorAll("[data-tab]")) {
      b.addEventListener("click", () => this.show(b.dataset.tab));
    }
    // A tab switch never acts on the click that caused it: a double click on a fleet row
    // opened the Vehicle tab with its first click, and its second landed on the Release
    // button that had just appeared under the pointer. The rest of a multiple click
    // (detail 2, 3, ...) that lands in the pane a click has just shown is dropped.
    window.addEventListener("click", (e) => {
      const s = this.switched;
      if (s && e.detail > 1 && e.timeStamp - s.at < SETTLE_MS && s.pane.contains(e.target)) {
        e.stopPropagation();
        e.preventDefault();
      }
      this.clicking = e; // a tab shown while this click is handled was shown by it
    }, true);
    window.addEventListener("click", () => { this.clicking = null; });
    this.show(PHONE.matches ? "map" : "fleet");
    PHONE.addEventListener("change", () => ctx.map.map.invalidateSize());
  }

  show(tab) {
    const ctx = this.ctx;
    if (this.clicking && ctx.app.dataset.tab !== tab) {
      const pane = tab === "map" ? $("map-pane") : document.querySelector(`.side [data-pane="${tab}"]`);
      if (pane) this.switched = { at: this.clicking.timeStamp, pane };
    }
    ctx.app.dataset.tab = tab;
    for (const b of document.querySelectorAll("[data-tab]")) {
      b.setAttribute("aria-selected", String(b.dataset.tab === tab));
    }
    if (tab === "map") {
      requestAnimationFrame(() => {
        ctx.map.map.invalidateSize();
        ctx.map.scheduleLabels(); // labels changed while hidden are measured now
      });
    }
    if (tab === "control") ctx.controlPanel.loadRequests();
    if (tab === "replay" && ctx.replay) ctx.replay.opened(); // its window up to now
    if (tab === "vehicle") ctx.vehiclePanel.show(ctx.focused);
  }
}
