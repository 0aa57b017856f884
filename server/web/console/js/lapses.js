// This user's control of a vehicle ending without the console hearing why: its link was
// down when the lease lapsed, was revoked or passed on, so no event came. Said once the
// view shows it, unless the event that says why comes just after.

import { toast } from "./ui.js";

const WAIT_MS = 1500; // the event may come a moment after the control change

export class ControlLapses {
  constructor(ctx) {
    this.ctx = ctx;
    this.held = new Map(); // vehicle id -> whether this user held it, as last seen
    this.toldAt = new Map(); // vehicle id -> when an event about its control was said
    ctx.fleet.addEventListener("change", (e) => {
      if (e.detail.what === "control" || e.detail.what === "view") this.check(e.detail.id);
    });
  }

  /** An event about the vehicle's control came (and was said, or was this user's own). */
  told(id) {
    this.toldAt.set(id, Date.now());
  }

  mine(id) {
    const v = this.ctx.fleet.vehicles.get(id);
    return Boolean(v && v.control && v.control.holder === this.ctx.me.username);
  }

  check(id) {
    const now = this.mine(id);
    const was = this.held.get(id) || false;
    this.held.set(id, now);
    if (!was || now) return;
    const at = Date.now();
    setTimeout(() => {
      if ((this.toldAt.get(id) || 0) >= at - WAIT_MS || this.mine(id)) return;
      const v = this.ctx.fleet.vehicles.get(id);
      const name = v ? v.view.name || id : id;
      toast(`you no longer hold control of ${name}: it ended while this console was out of ` +
        "contact (see What happened)", "error");
    }, WAIT_MS);
  }
}
