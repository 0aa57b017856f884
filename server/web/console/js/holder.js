// Who holds control of the selected boats, said over the map on a phone. A wider screen
// has the vehicle panel beside the map; a phone shows one view at a time, and its map
// said nothing of it: whoever was about to command a boat (or watched one) had to leave
// the map to learn who held it. The panel's own words (panels.js, controlSaid); the line
// is drawn again as control changes, and shown by the stylesheet on a phone only.

import { controlSaid, throttled } from "./panels.js";
import { h, until } from "./ui.js";

const MOST = 3; // lines at most, then "+N more" (the Fleet tab has every one)

export class MapHolder {
  constructor(ctx) {
    this.ctx = ctx;
    this.el = document.getElementById("map-holder");
    this.render = throttled(() => this.draw());
    ctx.fleet.addEventListener("change", (e) => {
      if (e.detail.what === "control" && ctx.selection.has(e.detail.id)) this.render();
    });
  }

  draw() {
    const { fleet, me, selection } = this.ctx;
    const vehicles = [...selection].map((id) => fleet.vehicles.get(id)).filter(Boolean);
    this.el.hidden = !vehicles.length; // and in a replay (the stylesheet): not live
    if (this.el.hidden) return;
    const several = vehicles.length > 1; // then each line names its boat
    const lines = vehicles.slice(0, MOST).map((v) => h("div.holder-line", {
      dataset: { vehicle: v.id },
    },
    several ? h("span.holder-name", {}, `${v.view.name || v.id}: `) : null,
    controlSaid(v.control, me),
    v.control ? [" ", h("small.until", { dataset: { until: v.control.expires_at } },
      `(${until(v.control.expires_at)})`)] : null));
    const more = vehicles.length - MOST;
    this.el.replaceChildren(...lines, more > 0 ? h("div.hint", {}, `+${more} more (Fleet tab)`) : "");
  }
}
