// The action bar over the map, for the selected vehicles: the tools a click on the map
// finishes (Go to, Keep station, a Path's waypoints drawn, Undo, Cancel, Send path), Hold,
// Stop and Stop all, with the options typed (speed, station radius); what it says of the
// selection. Each command goes through commands.js.

import { readNumber, sending, toast } from "./ui.js";
import { wireLon } from "./wrap.js";

const $ = (id) => document.getElementById(id);
const TOUCH = window.matchMedia("(pointer: coarse)"); // a finger: no Esc, no ctrl-click

export class Tools {
  constructor(ctx) {
    this.ctx = ctx;
    this.tool = null;
    this.draftPath = [];
    for (const b of document.querySelectorAll("[data-tool]")) {
      b.addEventListener("click", () => this.set(this.tool === b.dataset.tool ? null : b.dataset.tool));
    }
    // each button that sends is disabled while its call is in flight (ui.js, sending)
    $("hold").addEventListener("click", () => sending("hold", async () => {
      const radius = this.radius();
      if (radius != null) await ctx.commands.send("keep_station", { radius_m: radius });
    }));
    $("stop-selected").addEventListener("click",
      () => sending("stop", () => ctx.commands.stopSelected()));
    $("stop-all").addEventListener("click",
      () => sending("stop-all", () => ctx.commands.stopAll()));
    $("path-undo").addEventListener("click", () => {
      this.draftPath.pop();
      this.drawDraft();
    });
    $("path-cancel").addEventListener("click", () => this.set(null));
    $("path-send").addEventListener("click", () => sending("path", () => this.sendPath()));
    document.addEventListener("keydown", (e) => {
      if (e.key === "Escape" && this.tool) this.set(null);
    });
  }

  /** The bar for the ``selection`` (a Set of vehicle ids): hidden when it is empty, in a
   * replay, or for a viewer; its tool put away when nothing is selected. */
  showFor(selection) {
    const { app, fleet, me } = this.ctx;
    const n = selection.size;
    // a viewer reads: no command tools (the server would refuse every one)
    const reads = me.role === "viewer";
    $("actions").hidden = n === 0 || app.dataset.replay === "on" || reads;
    const names = [...selection].map((id) => fleet.vehicles.get(id)?.view.name || id);
    $("selection").textContent = n ? `${n} selected: ${names.join(", ")}` : "";
    $("stop-selected").textContent = n > 1 ? `Stop ${n}` : "Stop";
    this.showPlan(n);
    if (!n) this.set(null);
  }

  /** "plan round obstacles" for ``n`` selected: the planner keeps boats apart, so one
   * planned path cannot take several of them. Then the box is off, unticked (the path
   * goes as drawn) and says why beside it (a phone shows no tooltip); for one boat it is
   * ticked again as the person left it. */
  showPlan(n) {
    const plan = $("path-plan");
    const several = n > 1;
    if (several && !plan.disabled) this.planWanted = plan.checked;
    if (!several && plan.disabled) plan.checked = this.planWanted ?? true;
    if (several) plan.checked = false;
    plan.disabled = several;
    $("path-plan-why").hidden = !several;
  }

  /** Take up ``tool`` ("go_to", "station", "path"), or put it away (null). */
  set(tool) {
    this.tool = tool;
    for (const b of document.querySelectorAll("[data-tool]")) {
      b.classList.toggle("active", b.dataset.tool === tool);
      b.setAttribute("aria-pressed", String(b.dataset.tool === tool));
    }
    const hints = TOUCH.matches
      ? {
        go_to: "Tap the map where the selected vehicles should go (tap Go to again: cancel).",
        station: "Tap the map where the selected vehicles should keep station " +
          "(tap Keep station again: cancel).",
        path: "Tap the map to add waypoints.", // Send path and Cancel are under it
      }
      : {
        go_to: "Click the map where the selected vehicles should go (Esc: cancel).",
        station: "Click the map where the selected vehicles should keep station (Esc: cancel).",
        path: "Click the map to add waypoints, then Send path (Esc: cancel).",
      };
    $("tool-hint").hidden = !tool;
    $("tool-hint").textContent = hints[tool] || "";
    $("path-bar").hidden = tool !== "path";
    this.ctx.app.dataset.tool = tool || "";
    const map = this.ctx.map.map;
    if (tool === "path") map.doubleClickZoom.disable();
    else map.doubleClickZoom.enable();
    if (tool !== "path") {
      this.draftPath = [];
      this.drawDraft();
    }
  }

  drawDraft() {
    this.ctx.map.showDraft(this.draftPath);
    $("path-count").textContent = `${this.draftPath.length} waypoint${this.draftPath.length === 1 ? "" : "s"}`;
  }

  mapClicked(latlng) {
    const { commands, map } = this.ctx;
    // east of 180 on a map panned across it: the longitude the server takes (±180)
    const point = { lat: +latlng.lat.toFixed(7), lon: +wireLon(latlng.lng).toFixed(7) };
    if (this.tool === "go_to") {
      const speed = this.speedArg();
      if (speed == null) return; // said why; the tool stays for another click
      map.flash(latlng);
      commands.send("go_to", { ...point, ...speed });
      this.set(null);
    } else if (this.tool === "station") {
      const radius = this.radius();
      if (radius == null) return;
      map.flash(latlng);
      commands.send("keep_station", { ...point, radius_m: radius });
      this.set(null);
    } else if (this.tool === "path") {
      this.draftPath.push(point);
      this.drawDraft();
    }
  }

  /** The speed option: {} when left empty (the vehicle's own), ``{speed_mps}``, or null
   * (said in a toast) when it is not a plain number in the field's range: nothing is sent
   * then. */
  speedArg() {
    const field = $("opt-speed");
    const got = readNumber(field, { what: "speed", unit: "m/s", optional: "the vehicle's own" });
    if (got.error) return this.badNumber(field, got.error);
    return got.value === undefined ? {} : { speed_mps: got.value };
  }

  /** The station radius in metres, or null (said in a toast) when it is not a plain
   * number in its range. */
  radius() {
    const field = $("opt-radius");
    const got = readNumber(field, { what: "station radius", unit: "m" });
    return got.error ? this.badNumber(field, got.error) : got.value;
  }

  badNumber(field, error) {
    toast(error, "error");
    field.focus();
    return null;
  }

  async sendPath() {
    if (!this.draftPath.length) return toast("click the map to add waypoints first", "error");
    const speed = this.speedArg();
    if (speed == null) return undefined;
    const args = { waypoints: this.draftPath, ...speed };
    if ($("path-plan").checked && !$("path-plan").disabled) args.plan = true; // one boat
    if (await this.ctx.commands.send("follow_path", args)) this.set(null);
    return undefined;
  }
}
