// The control panel: a field manager's requests, grants and leases, and an operator's
// own; "What happened" (the control and safety events). Redraws from the Fleet state.

import { controlOffer, grantForm, holdAfter, holdText, mayTakeOver } from "./grants.js";
import { ControlLapses } from "./lapses.js";
import { commandName } from "./fleet.js";
import { describeEvent, holderText, kindName, presenceBadge, throttled } from "./panels.js";
import { clock, confirmAction, dateTime, h, sending, sends, toast, until } from "./ui.js";

const DURATIONS = [
  [300, "5 min"], [900, "15 min"], [1800, "30 min"], [3600, "1 h"], [7200, "2 h"],
  [14400, "4 h"], [28800, "8 h"], [86400, "24 h"],
];
// How "What happened" names an event's kind, so that a line reads as a sentence beside
// the vehicle's name; the others as everywhere (describe.js, kindName).
const KIND_LABELS = {
  control_mode: "control mode",
  presence: "is now",
  command: "command",
};
// How long after this console ended a lease its hold_station event is taken as said.
const ENDED_HERE_MS = 15000;
// A request of a server that does not say when it is dropped: the server's default TTL.
const REQUEST_SHOWN_MS = 600000;
// A press on the panel holds its redraws until it has become a click: a button replaced
// under a finger mid-tap lost the tap (a Grant on a phone did nothing). Held this long
// after the press ends, and never longer than PRESS_MAX_MS.
const PRESS_AFTER_MS = 350;
const PRESS_MAX_MS = 5000;
const SAFETY_EVENTS = new Set([
  "hold_station", "failsafe_entered", "failsafe_left", "failsafe_changed", "zone_breach",
  "zone_cleared", "collision_risk", "low_battery",
]);
// How long the holder's client may be silent before the lease lapses (operator_timeout_s).
const LIVENESS = [
  [0, "never"], [10, "10 s"], [30, "30 s"], [60, "1 min"], [300, "5 min"],
];

/** Whether "What happened" lists the event: control and safety, not the routine mode
 * changes of every mission (idle ⇄ remote); a crew taking the local controls, or a
 * failsafe, is listed; so is a stop, whoever sent it, and a vehicle gone offline (its
 * return is listed by the caller, which knows it was offline). */
function isSafetyEvent(e) {
  const d = e.data || {};
  if (e.kind === "control_mode") {
    return [d.control_mode, d.was].some((m) => m === "local" || m === "failsafe");
  }
  if (e.kind === "presence") return d.presence === "offline";
  if (e.kind === "command") return d.type === "stop" && d.status === "queued";
  return e.kind.startsWith("control_") || SAFETY_EVENTS.has(e.kind);
}

export class ControlPanel {
  constructor(ctx) {
    this.ctx = ctx;
    this.el = document.getElementById("control-pane");
    this.requests = [];
    this.mine = new Map(); // this user's requests not answered: instance id → until (ms)
    this.caps = new Map();
    this.render = throttled(() => this.draw());
    this.pressed = null; // the timer that ends a press, while one is under way
    this.held = false; // a redraw asked during the press
    this.el.addEventListener("pointerdown", () => this.press(PRESS_MAX_MS));
    for (const kind of ["pointerup", "pointercancel"]) {
      document.addEventListener(kind, () => { if (this.pressed) this.press(PRESS_AFTER_MS); }, true);
    }
    this.lapses = new ControlLapses(ctx);
    ctx.fleet.addEventListener("change", (e) => {
      const what = e.detail.what;
      if (what === "control" || what === "view" || what === "events") this.render();
    });
    ctx.fleet.addEventListener("event", (e) => {
      const { id, event } = e.detail;
      if (event.kind.startsWith("control_")) {
        this.loadRequests();
        this.lapses.told(id);
      }
      // a hold this console caused (a revoke, a release, a grant over a holder) was said
      // with it, once: not again in other words
      if (event.kind === "hold_station" && this.managed(id) && !this.endedHere(id)) {
        toast(this.holdSaid(id, event), "warn");
      }
      this.tellStops(id, event);
      this.tellMine(id, event);
    });
  }

  /** A manager hears of a stop someone else sent to a vehicle it manages: one toast for
   * a Stop all (the stops that come within half a second, by sender). */
  tellStops(id, event) {
    const d = event.data || {};
    const by = (event.actor || "").replace(/^user:/, "");
    if (event.kind !== "command" || d.type !== "stop" || d.status !== "queued") return;
    const v = this.ctx.fleet.vehicles.get(id);
    const holding = v && v.control && v.control.holder === this.ctx.me.username;
    if (!(this.managed(id) || holding) || !by || by === this.ctx.me.username) return;
    this.stops = this.stops || new Map();
    const ids = this.stops.get(by);
    if (ids) {
      ids.add(id);
      return;
    }
    this.stops.set(by, new Set([id]));
    setTimeout(() => {
      const all = [...this.stops.get(by)];
      this.stops.delete(by);
      // a boat out of contact gets it only when back: "stopped" would say it had happened
      const away = (x) => {
        const boat = this.ctx.fleet.vehicles.get(x);
        return Boolean(boat) && boat.view.presence !== "online";
      };
      const names = (list) => list.map((x) => this.nameOf(x)).sort().join(", ");
      const here = all.filter((x) => !away(x));
      const gone = all.filter(away);
      const said = [
        here.length ? `${by} stopped ${names(here)}` : null,
        gone.length ? `${here.length ? "and sent" : `${by} sent`} a stop to ${names(gone)}, ` +
          "out of contact: it reaches the boat only when back" : null,
      ].filter(Boolean).join(" ");
      toast(said, "warn");
    }, 500);
  }

  /** A lease this console is ending (a revoke, a release, a grant to another): the
   * hold_station event that follows is not said again. */
  ending(id) {
    this.ended = this.ended || new Map();
    this.ended.set(id, Date.now());
  }

  endedHere(id) {
    return Date.now() - ((this.ended && this.ended.get(id)) || 0) < ENDED_HERE_MS;
  }

  /** A hold at a lease's end as a toast: "Bravo: ana's control ended (revoked); it holds
   * station", or, out of contact, that the hold is only queued. */
  holdSaid(id, event) {
    const d = event.data || {};
    const name = this.nameOf(id);
    const v = this.ctx.fleet.vehicles.get(id);
    const why = String(d.reason || "ended").replace(/_/g, " ");
    const whose = d.holder ? `${d.holder}'s control` : "control";
    if (d.stop_kept) return `${name}: ${whose} ended (${why}); the stop already sent to it holds it`;
    return `${name}: ${whose} ended (${why}); ${holdAfter(name, v && v.view.presence)}`;
  }

  nameOf(id) {
    const v = this.ctx.fleet.vehicles.get(id);
    return v ? v.view.name || id : id;
  }

  /** What happens to this user's own control, and (for a manager) who asks for it, as a
   * toast whatever tab is open: nobody learns of it by chance in a side panel. */
  tellMine(id, event) {
    const me = this.ctx.me.username;
    const d = event.data || {};
    const by = (event.actor || "").replace(/^user:/, "");
    const name = this.nameOf(id);
    const v = this.ctx.fleet.vehicles.get(id);
    // out of contact the hold at a lease's end is only queued: never "it holds station"
    const hold = holdAfter(name, v && v.view.presence);
    if (v && ["control_grant", "control_deny"].includes(event.kind)
      && (d.holder === me || d.user === me)) {
      this.mine.delete(v.view.instance_id); // answered (the list is asked for again, too)
    }
    if (event.kind === "control_request" && this.managed(id) && by !== me) {
      toast(`${by} asks for control of ${name}: see Control`, "info");
    } else if (event.kind === "control_grant" && d.replaces === me && d.holder !== me && by !== me) {
      toast(`control of ${name} passed to ${d.holder} (granted by ${by}); ${hold}`, "error");
    } else if (event.kind === "control_grant" && d.holder === me && by !== me) {
      const lapse = d.operator_timeout_s
        ? `; it lapses if all your consoles are silent for ${d.operator_timeout_s} s` : "";
      toast(`you now hold control of ${name} (granted by ${by}${lapse})`, "ok");
    } else if (event.kind === "control_deny" && d.user === me) {
      toast(`${by} declined your request for ${name}${d.reason ? `: ${d.reason}` : ""}`, "error");
    } else if (event.kind === "control_revoke" && d.holder === me && by !== me) {
      toast(`your control of ${name} was revoked by ${by || "the server"}; ${hold}`, "error");
    } else if (event.kind === "control_expired" && d.holder === me) {
      const why = d.reason === "operator_silent" ? "this console was silent too long" : "its time ran out";
      toast(`your control of ${name} ended (${why}); ${hold}`, "error");
    }
  }

  get manages() {
    return this.ctx.me.role === "manager" || this.ctx.me.role === "admin";
  }

  managed(id) {
    const me = this.ctx.me;
    return me.role === "admin" || (me.role === "manager" && me.vehicles.includes(id));
  }

  /** Until when this user's request for the vehicle stands (ms), or 0: none pending. */
  requestedUntil(v) {
    const until = this.mine.get(v.view.instance_id) || 0;
    return until > Date.now() ? until : 0;
  }

  /** Requests this user made, until answered or dropped: ``requests`` as the server gives
   * them (from a request, or the list of one's own); ``all``: they are all there are. */
  asked(requests, all = false) {
    const before = this.mine;
    this.mine = all ? new Map() : new Map(before);
    for (const r of requests) {
      this.mine.set(r.instance_id, Date.parse(r.expires_at || "") || Date.now() + REQUEST_SHOWN_MS);
    }
    for (const v of this.ctx.fleet.vehicles.values()) {
      const id = v.view.instance_id;
      if (before.get(id) === this.mine.get(id)) continue;
      this.ctx.fleet.changed(v.id, "control");
      if (all && !this.mine.has(id) && before.get(id) <= Date.now()) { // nobody answered
        toast(`your request for control of ${v.view.name || v.id} was not answered in time: ` +
          "ask again, or call the field manager", "warn");
      }
    }
    // the first to be dropped unanswered: the buttons offer to ask again then
    clearTimeout(this.dropTimer);
    const next = Math.min(...this.mine.values());
    if (Number.isFinite(next)) this.dropTimer = setTimeout(() => this.loadMine(), Math.max(0, next - Date.now()) + 1000);
  }

  /** The requests this user made that nobody has answered yet, as the server has them
   * (a reload, a reconnect, a request dropped unanswered, a grant to someone else). */
  async loadMine() {
    if (this.ctx.me.role === "viewer") return;
    try {
      this.asked((await this.ctx.api.get("/client/control_requests?mine=true")).requests || [], true);
    } catch (e) {
      // the buttons stay as they were: the next control event or reconnect asks again
    }
  }

  async loadRequests() {
    this.loadMine();
    if (!this.manages) return;
    try {
      this.requests = (await this.ctx.api.get("/client/control_requests")).requests || [];
      // an admin may list every user (the grant form's pick list); a manager may not
      if (this.ctx.me.role === "admin" && !this.users) {
        this.users = (await this.ctx.api.get("/api/users")).users || [];
      }
    } catch (e) {
      toast(`control requests: ${e.message}`, "error");
    }
    this.render();
  }

  async capabilities(v) {
    if (this.caps.has(v.id) || !v.view.instance_id) return;
    this.caps.set(v.id, null);
    try {
      const got = await this.ctx.api.post("/client/connect_instance", { vehicle_id: v.id });
      this.caps.set(v.id, got.instance.capabilities || []);
      this.render();
    } catch {
      this.caps.delete(v.id);
    }
  }

  vehicleOf(instanceId) {
    return [...this.ctx.fleet.vehicles.values()].find((v) => v.view.instance_id === instanceId);
  }

  durationSelect(name) {
    return h("select", { name, "aria-label": "duration" },
      ...DURATIONS.map(([s, label]) => h("option", { value: s, selected: s === 3600 }, label)));
  }

  /** The lease lapses (and the vehicle holds station) when the holder's client is silent. */
  livenessSelect(name) {
    return h("select", {
      name, "aria-label": "lapse when the operator's client is silent for",
      title: "lapse when the operator's client is silent for",
    }, ...LIVENESS.map(([s, label]) => h("option", { value: s },
      s ? `lapses after ${label} silent` : "never lapses")));
  }

  /** A press under way, over in ``ms``: then the redraw it held, if any. */
  press(ms) {
    clearTimeout(this.pressed);
    this.pressed = setTimeout(() => {
      this.pressed = null;
      if (this.held) {
        this.held = false;
        this.render();
      }
    }, ms);
  }

  draw() {
    if (this.pressed) {
      this.held = true; // after the press (see PRESS_AFTER_MS)
      return;
    }
    const tab = document.querySelector('.tabs [data-tab="control"]');
    if (tab) tab.textContent = this.manages && this.requests.length ? `Control (${this.requests.length})` : "Control";
    const drawn = document.createElement("div");
    drawn.append(h("h2", {}, "Control"));
    if (this.manages) drawn.append(this.requestSection(), grantForm(this));
    drawn.append(this.leaseSection(), this.safetyLog());
    // Asked on every control, view or event change of any vehicle, most of which (a
    // position, another boat's link) change nothing here: the panel is replaced only
    // when what it shows has changed, so a button is not swapped under a finger or a
    // pointer for nothing. A countdown ("in 9 min") is left out of the comparison: the
    // clock's tick keeps it current in place, and its minute turning is no change.
    const probe = drawn.cloneNode(true);
    for (const el of probe.querySelectorAll("small.until")) el.textContent = "";
    const html = probe.innerHTML;
    if (html === this.shown) return;
    this.shown = html;
    // What the manager has chosen or typed in its forms (a duration, a user, the grant
    // form open) stays.
    const kept = this.formState();
    this.el.replaceChildren(...drawn.childNodes);
    this.restoreFormState(kept);
  }

  formState() {
    const fields = new Map();
    for (const el of this.el.querySelectorAll("form[data-key] [name]")) {
      fields.set(`${el.form.dataset.key}/${el.name}`, el.value);
    }
    const active = document.activeElement;
    const focus = active && active.form && active.form.dataset.key && this.el.contains(active)
      ? {
        key: `${active.form.dataset.key}/${active.name}`,
        caret: active.tagName === "INPUT" ? [active.selectionStart, active.selectionEnd] : null,
      }
      : null;
    const grant = this.el.querySelector("details.grant");
    return { fields, focus, grantOpen: Boolean(grant && grant.open) };
  }

  restoreFormState({ fields, focus, grantOpen }) {
    const grant = this.el.querySelector("details.grant");
    if (grant && grantOpen) grant.open = true; // first: a closed one's fields take no focus
    for (const el of this.el.querySelectorAll("form[data-key] [name]")) {
      const key = `${el.form.dataset.key}/${el.name}`;
      if (fields.has(key)) {
        const value = fields.get(key);
        if (el.tagName !== "SELECT" || [...el.options].some((o) => o.value === value)) {
          el.value = value;
        }
      }
      if (focus && key === focus.key) {
        el.focus();
        if (focus.caret) el.setSelectionRange(...focus.caret);
      }
    }
  }

  requestSection() {
    const items = this.requests.map((r) => {
      const v = this.vehicleOf(r.instance_id);
      const name = v ? v.view.name || v.id : r.instance_id;
      const form = h("form.request", {
        dataset: {
          user: r.username,
          vehicle: v ? v.id : "",
          key: `request/${r.request_id || `${r.username}/${r.instance_id}`}`,
        },
        onsubmit: (e) => {
          e.preventDefault();
          const f = e.target;
          this.grant(r.instance_id, r.username, +f.duration.value, +f.liveness.value);
        },
      },
      h("div", {}, h("b", {}, r.username), " asks for ", h("b", {}, name),
        h("br"), h("small", {}, `since ${clock(r.requested_at)}`)),
      h("div.row", {}, this.durationSelect("duration"), this.livenessSelect("liveness"),
        h("button.primary", { type: "submit", ...sends(`grant/${r.instance_id}`) }, "Grant"),
        h("input.reason", {
          name: "reason", maxLength: 200, placeholder: "reason (optional)",
          "aria-label": `why ${r.username}'s request is declined (optional)`,
          // Enter in the card's form would grant: a reason is for declining
          onkeydown: (e) => { if (e.key === "Enter") e.preventDefault(); },
        }),
        h("button.quiet.deny", {
          type: "button",
          ...sends(`deny/${r.instance_id}/${r.username}`),
          onclick: (e) => this.deny(r.instance_id, r.username, name,
            e.target.form.reason.value.trim()),
        }, "Decline")));
      return h("li", {}, form);
    });
    return h("section.requests", {},
      h("h3", {}, `Requests for control (${this.requests.length})`),
      items.length ? h("ul.cards", {}, ...items) : h("p.hint", {}, "none pending"));
  }

  leaseSection() {
    const { fleet, me } = this.ctx;
    const rows = [...fleet.vehicles.values()]
      .filter((v) => v.view.presence !== "finished" || v.control)
      .sort((a, b) => (a.id < b.id ? -1 : 1))
      .map((v) => {
        const c = v.control;
        const mine = c && c.holder === me.username;
        if (c) this.capabilities(v);
        const caps = (this.caps.get(v.id) || []).filter((k) => k !== "stop");
        return h("li.lease", { dataset: { vehicle: v.id } },
          h("div", {}, h("b", {}, v.view.name || v.id), " ", presenceBadge(v.view.presence)),
          c
            ? h("div", {}, h("b", {}, holderText(c, me)), ` until ${clock(c.expires_at)} `,
              h("small.until", { dataset: { until: c.expires_at } }, `(${until(c.expires_at)})`),
              h("p.allows", {},
                `allows ${holderText(c, me)} to send ${caps.length ? caps.map(commandName).join(", ") : "its missions"}` +
                ` to ${v.view.name || v.id} until ${dateTime(c.expires_at)}; ` +
                "any operator or manager who sees the vehicle may still stop it." +
                (c.operator_timeout_s
                  ? ` It lapses (and the vehicle holds station) if every console of ${mine ? "yours" : "theirs"}` +
                    ` is silent for ${c.operator_timeout_s} s` +
                    (mine ? ": this console keeps it alive while it is open, and so does any other you have open."
                      : "; any console of theirs left open keeps it alive.")
                  : ` It never lapses on silence: it stays ${mine ? "yours" : "theirs"} with ` +
                    `${mine ? "your" : "their"} console closed, until it ends, is released or ` +
                    "is revoked.")))
            : h("div.hint", {}, "nobody holds control"),
          h("div.row", {},
            // another's lease: one's own is released (as in the vehicle panel)
            c && !mine && this.managed(v.id)
              ? h("button", { ...sends(`revoke/${v.id}`), onclick: () => this.revoke(v) }, "Revoke")
              : null,
            mine ? h("button", {
              ...sends(`release/${v.id}`), onclick: () => this.ctx.commands.releaseControl(v.id),
            }, "Release") : null,
            mine ? null : controlOffer(this.ctx, v, "Request")));
      });
    return h("section", {}, h("h3", {}, "Leases"), h("ul.cards", {}, ...rows));
  }

  /** What happened to control and safety across the fleet: leases ending, vehicles
   * holding station, failsafes, zones, collision forecasts (newest first). */
  safetyLog() {
    const items = [];
    for (const v of this.ctx.fleet.vehicles.values()) {
      let offline = false; // back online after being offline: listed too
      for (const e of [...v.events].sort((a, b) => (a.at < b.at ? -1 : 1))) {
        const back = e.kind === "presence" && offline && (e.data || {}).presence === "online";
        if (e.kind === "presence") offline = (e.data || {}).presence === "offline";
        if (back || isSafetyEvent(e)) items.push([v, e]);
      }
    }
    items.sort((a, b) => (a[1].at < b[1].at ? 1 : -1));
    const rows = items.slice(0, 30).map(([v, e]) => h("li", { dataset: { kind: e.kind, vehicle: v.id } },
      h("time", {}, clock(e.at)), " ", h("b", {}, v.view.name || v.id), " ",
      h("span.kind", {}, KIND_LABELS[e.kind] || kindName(e.kind)), " ", describeEvent(e)));
    return h("section.safety-log", {}, h("h3", {}, "What happened"),
      rows.length ? h("ol.events", {}, ...rows) : h("p.hint", {}, "nothing yet"));
  }

  grant(instanceId, user, durationS, operatorTimeoutS = 0) {
    return sending(`grant/${instanceId}`, () => this.grantNow(instanceId, user, durationS, operatorTimeoutS));
  }

  async grantNow(instanceId, user, durationS, operatorTimeoutS) {
    if (!(await mayTakeOver(this, instanceId, user))) return null;
    const v = this.vehicleOf(instanceId);
    const name = v ? v.view.name || v.id : instanceId;
    const before = v && v.control;
    try {
      const body = { instance_id: instanceId, user, duration_s: durationS };
      if (operatorTimeoutS) body.operator_timeout_s = operatorTimeoutS;
      const lease = await this.ctx.api.post("/client/grant_control", body);
      if (before && before.holder === lease.holder
        && Date.parse(lease.expires_at) <= Date.parse(before.expires_at)) {
        // granted again for less than is left: the server keeps the lease as it was
        toast(`${lease.holder} already holds ${name} until ${clock(lease.expires_at)}; ` +
          "a grant never shortens a lease", "info");
      } else {
        toast(`control of ${name} granted to ${lease.holder} until ${clock(lease.expires_at)}`, "ok");
      }
      if (v) this.ctx.fleet.applyControl(v.id, { control: lease });
    } catch (e) {
      toast(`grant refused: ${e.explain ? e.explain() : e.message}`, "error");
      this.loadRequests();
      // the user named is refused (unknown, disabled, not allowed the vehicle): said by
      // the grant form too
      const details = Array.isArray(e.details) ? e.details : [];
      return details.some((d) => d.field === "user") ? e.message : null;
    }
    this.loadRequests();
    return null;
  }

  deny(instanceId, user, name, reason = "") {
    return sending(`deny/${instanceId}/${user}`, async () => {
      try {
        const body = { instance_id: instanceId, user, ...(reason ? { reason } : {}) };
        await this.ctx.api.post("/client/deny_control", body);
        toast(`${user}'s request for ${name} declined${reason ? `: ${reason}` : ""}`, "ok");
      } catch (e) {
        toast(`decline refused: ${e.explain ? e.explain() : e.message}`, "error");
      }
      this.loadRequests();
    });
  }

  revoke(v) {
    return sending(`revoke/${v.id}`, () => this.revokeNow(v));
  }

  async revokeNow(v) {
    const name = v.view.name || v.id;
    const holder = v.control ? v.control.holder : "its holder";
    const ok = await confirmAction({
      title: `Revoke ${holder}'s control of ${name}?`,
      text: `${holdText(name, v.view.presence)}; the commands ${holder} queued and it has ` +
        "not begun are cancelled.",
      confirm: "Revoke",
    });
    if (!ok) return;
    try {
      this.ending(v.id); // its hold_station event is said here, once
      await this.ctx.api.post("/client/revoke_control", { instance_id: v.view.instance_id });
      const online = v.view.presence === "online";
      toast(`control of ${name} revoked; ${holdAfter(name, v.view.presence)}`, online ? "ok" : "warn");
    } catch (e) {
      toast(`revoke refused: ${e.message}`, "error");
    }
  }
}
