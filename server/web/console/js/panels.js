// The side panels: the fleet table, the vehicle panel (parameters, presence, control,
// recent commands and events) and the control panel (a field manager's requests, grants
// and leases; an operator's own). Each redraws from the Fleet state when it changes.

import { isFinal, lastKnown, stageLabel, stageOf } from "./fleet.js";
import { ago, clock, confirmAction, dateTime, h, sending, sends, toast, until } from "./ui.js";

const DURATIONS = [
  [300, "5 min"], [900, "15 min"], [1800, "30 min"], [3600, "1 h"], [7200, "2 h"],
  [14400, "4 h"], [28800, "8 h"], [86400, "24 h"],
];
// Events the control panel's log shows beside control_*.
// How "What happened" names an event's kind, so that a line reads as a sentence.
const KIND_LABELS = {
  control_request: "control requested", control_grant: "control granted to",
  control_revoke: "control revoked from", control_release: "control released by",
  control_expired: "control expired for", control_deny: "request declined for",
  hold_station: "holds station:",
  control_mode: "control mode",
};
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
 * failsafe, is listed. */
function isSafetyEvent(e) {
  if (e.kind === "control_mode") {
    const d = e.data || {};
    return [d.control_mode, d.was].some((m) => m === "local" || m === "failsafe");
  }
  return e.kind.startsWith("control_") || SAFETY_EVENTS.has(e.kind);
}

function presenceBadge(presence) {
  return h(`span.presence.p-${presence || "offline"}`, {}, presence || "unknown");
}

/** A command's stage as a chip: greyed, "(last known)", when the vehicle is not online. */
function chip(cmd, presence) {
  if (!cmd) return "–";
  return h(`span.chip.stage-${cmd.stage}${lastKnown(cmd, presence) ? ".last-known" : ""}`, {},
    stageLabel(cmd, presence));
}

/** A delay in ms as the console shows it (tenths below 10 ms). */
function millis(x) {
  return `${x < 10 ? x.toFixed(1) : x.toFixed(0)} ms`;
}

/** How long "Requested…" stands on a request not yet answered (a manager may not be on). */
const REQUEST_SHOWN_MS = 120000;

/** The course over ground from the trail: the bearing from where the vehicle was about
 * 5 s before its last position to that position; "–" when it moved under a metre. */
export function courseText(trail) {
  if (!trail || trail.length < 2) return "–";
  const last = trail[trail.length - 1];
  let from = trail[trail.length - 2];
  for (let i = trail.length - 2; i >= 0 && last.t - trail[i].t <= 5000; i -= 1) from = trail[i];
  const rad = Math.PI / 180;
  const north = (last.lat - from.lat) * 111320;
  const east = (last.lon - from.lon) * 111320 * Math.cos(last.lat * rad);
  if (Math.hypot(north, east) < 1) return "–";
  return `${Math.round((Math.atan2(east, north) / rad + 360) % 360) % 360} °`;
}

/** The vehicle's link as the server measures it (docs/live.md, "Latency per hop"). */
/** A command's detail as people read it ("superseded_by go_to c-1": "superseded by go_to
 * c-1"; "superseded_by_stop": "superseded by a stop"). */
function readableDetail(detail) {
  if (detail === "superseded_by_stop") return "superseded by a stop";
  return String(detail).replace(/^superseded_by /, "superseded by ");
}

function linkText(view) {
  if (view.link_delay_ms == null) return null;
  const rtt = view.link_rtt_ms != null ? ` · ${millis(view.link_rtt_ms)} round trip` : "";
  return `${millis(view.link_delay_ms)} one way${rtt}`;
}

function holderText(control, me) {
  if (!control) return "nobody";
  return control.holder === me.username ? "you" : control.holder;
}

/** Redraw at most once a frame, however many changes come in. */
function throttled(fn) {
  let pending = false;
  return () => {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => {
      pending = false;
      fn();
    });
  };
}

// ---- the fleet table ------------------------------------------------------------------

export class FleetTable {
  constructor(ctx) {
    this.ctx = ctx;
    this.body = document.querySelector("#fleet-table tbody");
    this.render = throttled(() => this.draw());
    ctx.fleet.addEventListener("change", this.render);
  }

  draw() {
    const { fleet, me } = this.ctx;
    const rows = [...fleet.vehicles.values()].sort((a, b) => (a.id < b.id ? -1 : 1));
    this.body.replaceChildren(
      ...rows.map((v) => {
        const p = v.view.position;
        const selected = this.ctx.selection.has(v.id);
        const row = h(
          "tr",
          {
            dataset: { vehicle: v.id },
            class: selected ? "selected" : "",
            onclick: (e) => {
              if (e.target.type === "checkbox") return;
              this.ctx.pick(v.id, e.shiftKey || e.ctrlKey || e.metaKey);
              this.ctx.map.bringIntoView(v.id); // picked from the list: shown on the map
            },
          },
          h("td", {}, h("input", {
            type: "checkbox",
            checked: selected,
            "aria-label": `select ${v.id}`,
            onchange: () => this.ctx.pick(v.id, true),
          })),
          h("td", {}, h("b", {}, v.view.name || v.id), h("br"), h("small", {}, v.id)),
          h("td", {}, presenceBadge(v.view.presence), h("br"),
            h("small.ago", { dataset: { since: fleet.lastContact(v.id) } },
              ago(fleet.lastContact(v.id))),
            v.view.link_delay_ms != null
              ? [h("br"), h("small.link-delay", { title: "one-way delay to the server" },
                `link ${millis(v.view.link_delay_ms)}`)]
              : null),
          // a reading of a vehicle not online is greyed and dated, as in its panel
          v.view.presence === "online"
            ? h("td", {}, p && p.battery_pct != null ? `${p.battery_pct.toFixed(0)} %` : "–")
            : h("td.stale", { title: p ? `as of ${clock(p.ts)}` : null },
              p && p.battery_pct != null ? `${p.battery_pct.toFixed(0)} %` : "–"),
          h("td", {}, holderText(v.control, me)),
          h("td", {}, chip(fleet.latestCommand(v.id), v.view.presence)),
        );
        return row;
      }),
    );
  }
}

// ---- one vehicle ------------------------------------------------------------------------

export class VehiclePanel {
  constructor(ctx) {
    this.ctx = ctx;
    this.el = document.getElementById("vehicle-pane");
    this.id = null;
    this.params = null;
    this.render = throttled(() => this.draw());
    ctx.fleet.addEventListener("change", (e) => {
      if (e.detail.id === this.id) this.render();
    });
  }

  show(id) {
    if (id !== this.id) {
      this.id = id;
      this.params = null;
      this.loadParams();
    }
    this.render();
  }

  async loadParams() {
    const v = this.ctx.fleet.vehicles.get(this.id);
    if (!v || !v.view.instance_id) return;
    const id = this.id;
    try {
      const got = await this.ctx.api.get("/client/get_param", { instance_id: v.view.instance_id });
      if (id !== this.id) return;
      this.params = got;
      this.render();
    } catch (e) {
      this.params = { error: e.message };
      this.render();
    }
  }

  draw() {
    const { fleet, me } = this.ctx;
    const v = fleet.vehicles.get(this.id);
    if (!v) {
      this.el.replaceChildren(h("p.hint", {}, "Select a vehicle on the map or in the fleet."));
      return;
    }
    const view = v.view;
    const p = view.position || {};
    const num = (x, unit, digits = 1) => (x == null ? "–" : `${Number(x).toFixed(digits)} ${unit}`);
    const contact = fleet.lastContact(v.id);
    const control = v.control;
    const mine = control && control.holder === me.username;
    const controlRow = h(
      "div.control-line",
      {},
      control
        ? [h("b", {}, holderText(control, me)),
          ` ${mine ? "hold" : "holds"} control until ${clock(control.expires_at)} `,
          h("small.until", { dataset: { until: control.expires_at } }, `(${until(control.expires_at)})`),
          control.granted_by ? h("small", {}, ` granted by ${control.granted_by}`) : null]
        : "nobody holds control",
      control && !mine && this.ctx.controlPanel.managed(v.id)
        ? h("button", {
          ...sends(`revoke/${v.id}`), onclick: () => this.ctx.controlPanel.revoke(v),
        }, "Revoke")
        : null,
      me.role !== "viewer" && !mine && view.instance_id
        ? (v.requested && Date.now() - v.requested < REQUEST_SHOWN_MS
          ? h("button", { disabled: true, title: "the field manager decides" }, "Requested…")
          : h("button", {
            ...sends(`request/${v.id}`), onclick: () => this.ctx.requestControl(v.id),
          }, "Request control"))
        : null,
      mine ? h("button", {
        ...sends(`release/${v.id}`), onclick: () => this.ctx.releaseControl(v.id),
      }, "Release") : null,
    );
    const failsafe = view.failsafe
      ? h("p.failsafe", {}, h("b", {}, "If the link is lost: "), describeFailsafe(view.failsafe),
        view.failsafe_acked === false ? " (not yet acknowledged by the vehicle)" : "")
      : null;
    this.el.replaceChildren(...[
      h("h2", {}, view.name || v.id, " ", presenceBadge(view.presence)),
      h("p.sub", {}, `${v.id} · ${view.vehicle_type || "vehicle"} · mode ${view.control_mode || "–"}`),
      h("p", {}, "last contact ", h("b.ago", { dataset: { since: contact } }, ago(contact)),
        ` (${clock(contact)})`),
      failsafe,
      controlRow,
      view.presence && view.presence !== "online"
        ? h("p.stale-note", {}, `readings as of ${clock(p.ts)}: the vehicle is ${view.presence}`)
        : null,
      h(`dl.readings${view.presence && view.presence !== "online" ? ".stale" : ""}`, {},
        h("dt", {}, "position"), h("dd", {}, p.lat != null ? `${p.lat.toFixed(6)}, ${p.lon.toFixed(6)}` : "–"),
        h("dt", { title: "where the bow points" }, "heading"), h("dd", {}, p.heading_deg == null ? "–"
          : `${Math.round(p.heading_deg) % 360} °`), // 359.6 reads 0, not 360
        h("dt", { title: "where it moves, from its last positions" }, "course"),
        h("dd", {}, courseText(v.trail)),
        h("dt", {}, "speed"), h("dd", {}, num(p.speed_mps, "m/s")),
        h("dt", {}, "battery"), h("dd", {}, num(p.battery_pct, "%", 0)),
        h("dt", {}, "link"), h("dd.link-delay", {}, linkText(view) || "–"),
        p.depth_m != null ? [h("dt", {}, "depth"), h("dd", {}, num(p.depth_m, "m"))] : null),
      h("h3", {}, "Parameters ", h("button.quiet", {
        ...sends(`params/${v.id}`), onclick: () => sending(`params/${v.id}`, () => this.loadParams()),
      }, "refresh")),
      this.paramsTable(),
      h("h3", {}, "Recent commands"),
      this.commandList(v),
      h("h3", {}, "Recent events"),
      h("ol.events", {}, ...[...v.events].reverse().slice(0, 20).map((e) => h("li", {},
        h("time", {}, clock(e.at)), " ", h("b", {}, kindName(e.kind)), " ", describeEvent(e)))),
    ].filter(Boolean));
  }

  paramsTable() {
    if (!this.params) return h("p.hint", {}, "loading…");
    if (this.params.error) return h("p.error", {}, this.params.error);
    const entries = Object.entries(this.params.params || {});
    if (!entries.length) return h("p.hint", {}, "none reported");
    return h("table.params", {}, ...entries.map(([k, val]) => h("tr", {}, h("th", {}, k),
      h("td", {}, typeof val === "object" ? JSON.stringify(val) : String(val)))));
  }

  commandList(v) {
    const cmds = this.ctx.fleet.recentCommands(v.id).slice(0, 12);
    if (!cmds.length) return h("p.hint", {}, "none");
    return h("ol.commands", {}, ...cmds.map((c) => h(
      lastKnown(c, v.view.presence) ? "li.last-known" : "li",
      { dataset: { command: c.command_id, stage: c.stage } },
      h("b", {}, c.type), " ", h("span.steps", {}, c.stages.join(" → "),
        lastKnown(c, v.view.presence) ? " (last known)" : ""),
      c.progress != null && !isFinal(c.status) ? ` ${Math.round(c.progress * 100)} %` : "",
      h("br"),
      h("small", {}, `${clock(c.issued_at)}${c.issued_by ? ` by ${c.issued_by}` : ""}`,
        c.detail ? ` · ${readableDetail(c.detail)}` : ""),
      !isFinal(c.status) && this.mayCancel(v, c)
        ? h("button.quiet", {
          ...sends(`cancel/${c.command_id}`), onclick: () => this.ctx.cancelCommand(c.command_id),
        }, "cancel")
        : null,
    )));
  }

  /** Who the server lets cancel (docs/commands.md): the issuer, the control holder, a
   * manager of the vehicle or an admin. Offered to them only, not refused after a click. */
  mayCancel(v, c) {
    const me = this.ctx.me;
    if (me.role === "admin" || (me.role === "manager" && me.vehicles.includes(v.id))) return true;
    if (me.role === "viewer") return false;
    return c.issued_by === me.username || (v.control && v.control.holder === me.username);
  }
}

export function describeEvent(e) {
  const d = e.data || {};
  if (e.kind === "command") {
    const stage = d.status ? stageOf(d.status, d.detail) : "";
    const who = e.actor ? e.actor.replace(/^user:/, "") : null;
    // a cancel's detail is "by <who>": said once, not "(by ana) by ana"
    const detail = d.detail && d.detail !== "superseded_by_stop" && d.detail !== `by ${who}`
      ? ` (${d.detail.replace(/^superseded_by /, "by ")})` : "";
    return `${d.type || ""} ${stage}${detail}` + (who ? ` by ${who}` : "");
  }
  if (e.kind === "control_mode") {
    return `${d.was ? `${d.was} → ` : ""}${d.control_mode || "?"}`;
  }
  if (e.kind === "failsafe_changed") return describeFailsafe(d);
  if (e.kind === "zone_breach" || e.kind === "zone_cleared") {
    const what = d.message || `${e.kind === "zone_breach" ? "entered" : "left"} ${d.zone || "a zone"}`;
    const sent = d.command_type ? `; the server sent ${d.command_type.replace(/_/g, " ")}` : "";
    return `${what}${sent}`;
  }
  if (e.kind === "collision_risk") {
    const n = (x) => (x == null ? "?" : Math.round(x));
    return `with ${d.other_vehicle_id || "another vehicle"} in ${n(d.in_s)} s: ` +
      `closest ${n(d.closest_m)} m (${n(d.distance_now_m)} m apart now)`;
  }
  if (e.kind === "low_battery" || e.kind === "battery_recovered") {
    const pct = d.battery_pct == null ? "?" : Number(d.battery_pct).toFixed(0);
    return `${pct} % (alarm below ${d.threshold_pct ?? "?"} %)`;
  }
  if (e.kind === "failsafe_entered" || e.kind === "failsafe_left") {
    return `${d.was || "?"} → ${d.control_mode || "?"}`;
  }
  if (e.kind.startsWith("control_")) {
    const who = d.holder || d.user || d.username || "";
    const by = e.actor ? e.actor.replace(/^user:/, "") : "";
    const terms = e.kind === "control_grant" && d.expires_at
      ? ` until ${clock(d.expires_at)}` +
        (d.operator_timeout_s ? `, lapses after ${d.operator_timeout_s} s of silence` : "")
      : "";
    // "released by ben", not "released by ben (by ben)"
    return `${who}${terms}${d.reason ? `: ${String(d.reason).replace(/_/g, " ")}` : ""}` +
      `${by && by !== who ? ` (by ${by})` : ""}`;
  }
  if (e.kind === "hold_station") {
    const why = String(d.reason || "ended").replace(/_/g, " ");
    return `${d.holder ? `${d.holder}'s control ended` : "control ended"} (${why}); ` +
      `${d.type === "stop" ? "stopped" : "keeps station where it is"}`;
  }
  if (e.kind === "presence") return d.presence || "";
  if (e.kind === "instance") return d.action || "";
  if (e.kind === "failsafe_acked") return d.version != null ? `version ${d.version}` : "";
  return describeData(d);
}

// An event's kind as a person reads it ("failsafe applied", not failsafe_acked).
const KIND_NAMES = {
  failsafe_acked: "failsafe applied by the vehicle", failsafe_changed: "failsafe set",
  control_request: "control requested", control_deny: "control request declined",
  hold_station: "holds station", instance: "instance",
};

export function kindName(kind) {
  return KIND_NAMES[kind] || kind.replace(/_/g, " ");
}

/** A link-loss policy as a field manager reads it: "keep station where it is after 30 s
 * without the server; on a zone breach too · the server's default". */
export function describeFailsafe(f) {
  if (!f) return "";
  const what = {
    none: "carry on (no failsafe)",
    keep_station: "keep station where it is",
    stop: "stop",
    return_home: f.home ? `return home (${(+f.home.lat).toFixed(5)}, ${(+f.home.lon).toFixed(5)})`
      : "return home (where it started)",
  }[f.action] || String(f.action);
  const parts = [f.action === "none" ? what : `${what} after ${f.after_s ?? "?"} s without the server`];
  if (f.on_breach && f.action !== "none") parts.push("the same at once on a zone breach");
  if (f.low_battery_pct != null) parts.push(`low-battery alarm below ${f.low_battery_pct} %`);
  if (!f.version) parts.push("the server's default");
  return parts.join(" · ");
}

const UNITS = { s: " s", m: " m", pct: " %", mps: " m/s", deg: "°" };

/** An object as "key value · key value" (nulls left out, units from the key's suffix:
 * after_s 30 reads "after 30 s"; nested values as JSON). */
export function describeData(d) {
  return Object.entries(d || {})
    .filter(([, v]) => v !== null && v !== undefined)
    .map(([k, v]) => {
      const unit = k.match(/^(.*)_(s|m|pct|mps|deg)$/);
      const name = (unit ? unit[1] : k).replace(/_/g, " ");
      const value = typeof v === "object" ? JSON.stringify(v) : String(v);
      return `${name} ${value}${unit ? UNITS[unit[2]] : ""}`;
    })
    .join(" · ")
    .slice(0, 160);
}

// ---- control: requests, grants, leases -------------------------------------------------------

export class ControlPanel {
  constructor(ctx) {
    this.ctx = ctx;
    this.el = document.getElementById("control-pane");
    this.requests = [];
    this.caps = new Map();
    this.render = throttled(() => this.draw());
    ctx.fleet.addEventListener("change", (e) => {
      const what = e.detail.what;
      if (what === "control" || what === "view" || what === "events") this.render();
    });
    ctx.fleet.addEventListener("event", (e) => {
      const { id, event } = e.detail;
      if (event.kind.startsWith("control_")) this.loadRequests();
      if (event.kind === "hold_station" && this.managed(id)) {
        toast(`${this.nameOf(id)} holds station: ${describeEvent(event)}`, "info");
      }
      this.tellMine(id, event);
    });
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
    if (v && ["control_grant", "control_deny"].includes(event.kind)
      && (d.holder === me || d.user === me)) {
      v.requested = null; // answered
    }
    if (event.kind === "control_request" && this.managed(id) && by !== me) {
      toast(`${by} asks for control of ${name}: see Control`, "info");
    } else if (event.kind === "control_grant" && d.replaces === me && d.holder !== me && by !== me) {
      toast(`control of ${name} passed to ${d.holder} (granted by ${by}); it holds station`, "error");
    } else if (event.kind === "control_grant" && d.holder === me && by !== me) {
      toast(`you now hold control of ${name} (granted by ${by})`, "ok");
    } else if (event.kind === "control_deny" && d.user === me) {
      toast(`${by} declined your request for ${name}${d.reason ? `: ${d.reason}` : ""}`, "error");
    } else if (event.kind === "control_revoke" && d.holder === me && by !== me) {
      toast(`your control of ${name} was revoked by ${by || "the server"}; it holds station`, "error");
    } else if (event.kind === "control_expired" && d.holder === me) {
      const why = d.reason === "operator_silent" ? "this console was silent too long" : "its time ran out";
      toast(`your control of ${name} ended (${why}); it holds station`, "error");
    }
  }

  get manages() {
    return this.ctx.me.role === "manager" || this.ctx.me.role === "admin";
  }

  managed(id) {
    const me = this.ctx.me;
    return me.role === "admin" || (me.role === "manager" && me.vehicles.includes(id));
  }

  async loadRequests() {
    if (!this.manages) return;
    try {
      this.requests = (await this.ctx.api.get("/client/control_requests")).requests || [];
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
    }, ...LIVENESS.map(([s, label]) => h("option", { value: s }, s ? `silent ${label}` : `lapse: ${label}`)));
  }

  draw() {
    const tab = document.querySelector('.tabs [data-tab="control"]');
    if (tab) tab.textContent = this.manages && this.requests.length ? `Control (${this.requests.length})` : "Control";
    const parts = [h("h2", {}, "Control")];
    if (this.manages) parts.push(this.requestSection(), this.grantForm());
    parts.push(this.leaseSection(), this.safetyLog());
    // The panel is drawn again on every control, view or event change: what the manager
    // has chosen or typed in its forms (a duration, a user, the grant form open) stays.
    const kept = this.formState();
    this.el.replaceChildren(...parts);
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

  grantForm() {
    const vehicles = [...this.ctx.fleet.vehicles.values()].filter(
      (v) => this.managed(v.id) && v.view.instance_id && v.view.presence !== "finished",
    );
    return h("details.grant", {},
      h("summary", {}, "Grant control to someone"),
      h("form", {
        dataset: { key: "grant" },
        onsubmit: (e) => {
          e.preventDefault();
          const f = e.target;
          const v = this.ctx.fleet.vehicles.get(f.vehicle.value);
          sending("grant/form", () => this.grant(
            v.view.instance_id, f.user.value.trim(), +f.duration.value, +f.liveness.value,
          ));
        },
      },
      h("label", {}, "vehicle ", h("select", { name: "vehicle" },
        ...vehicles.map((v) => h("option", { value: v.id }, v.view.name || v.id)))),
      h("label", {}, "user ", h("input", { name: "user", required: true, autocomplete: "off" })),
      h("label", {}, "for ", this.durationSelect("duration")),
      h("label", {}, "lapse when their client is ", this.livenessSelect("liveness")),
      h("button.primary", { type: "submit", ...sends("grant/form") }, "Grant")));
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
                `allows ${holderText(c, me)} to send ${caps.length ? caps.join(", ") : "its missions"}` +
                ` to ${v.view.name || v.id} until ${dateTime(c.expires_at)}; ` +
                "anyone who sees the vehicle may still stop it." +
                (c.operator_timeout_s
                  ? ` It lapses (and the vehicle holds station) if ${mine ? "your" : "their"}` +
                    ` client is silent for ${c.operator_timeout_s} s` +
                    (mine ? ": this console keeps it alive while it is open." : ".")
                  : "")))
            : h("div.hint", {}, "nobody holds control"),
          h("div.row", {},
            c && this.managed(v.id)
              ? h("button", { ...sends(`revoke/${v.id}`), onclick: () => this.revoke(v) }, "Revoke")
              : null,
            mine ? h("button", {
              ...sends(`release/${v.id}`), onclick: () => this.ctx.releaseControl(v.id),
            }, "Release") : null,
            !mine && me.role !== "viewer" && v.view.instance_id
              ? h("button.quiet", {
                ...sends(`request/${v.id}`), onclick: () => this.ctx.requestControl(v.id),
              }, "Request")
              : null));
      });
    return h("section", {}, h("h3", {}, "Leases"), h("ul.cards", {}, ...rows));
  }

  /** What happened to control and safety across the fleet: leases ending, vehicles
   * holding station, failsafes, zones, collision forecasts (newest first). */
  safetyLog() {
    const items = [];
    for (const v of this.ctx.fleet.vehicles.values()) {
      for (const e of v.events) {
        if (isSafetyEvent(e)) items.push([v, e]);
      }
    }
    items.sort((a, b) => (a[1].at < b[1].at ? 1 : -1));
    const rows = items.slice(0, 15).map(([v, e]) => h("li", { dataset: { kind: e.kind, vehicle: v.id } },
      h("time", {}, clock(e.at)), " ", h("b", {}, v.view.name || v.id), " ",
      h("span.kind", {}, KIND_LABELS[e.kind] || e.kind.replace(/_/g, " ")), " ", describeEvent(e)));
    return h("section.safety-log", {}, h("h3", {}, "What happened"),
      rows.length ? h("ol.events", {}, ...rows) : h("p.hint", {}, "nothing yet"));
  }

  grant(instanceId, user, durationS, operatorTimeoutS = 0) {
    return sending(`grant/${instanceId}`, () => this.grantNow(instanceId, user, durationS, operatorTimeoutS));
  }

  async grantNow(instanceId, user, durationS, operatorTimeoutS) {
    if (!(await this.mayTakeOver(instanceId, user))) return;
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
    }
    this.loadRequests();
  }

  /** A grant to someone while another holds the vehicle ends that lease: asked first. */
  async mayTakeOver(instanceId, user) {
    const v = this.vehicleOf(instanceId);
    const c = v && v.control;
    if (!c || c.holder === user || !(Date.parse(c.expires_at) > Date.now())) return true;
    const name = v.view.name || v.id;
    const holder = holderText(c, this.ctx.me);
    return confirmAction({
      title: `Give control of ${name} to ${user}?`,
      text: `${holder} ${holder === "you" ? "hold" : "holds"} ${name} until ${clock(c.expires_at)}; ` +
        `give control to ${user} instead? ${holder === "you" ? "Your" : `${c.holder}'s`} commands ` +
        `it has not begun are cancelled and ${name} holds station.`,
      confirm: `Give it to ${user}`,
    });
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
      text: `${name} holds station at once; the commands ${holder} queued and it has not ` +
        "begun are cancelled.",
      confirm: "Revoke",
    });
    if (!ok) return;
    try {
      await this.ctx.api.post("/client/revoke_control", { instance_id: v.view.instance_id });
      toast(`control of ${v.view.name || v.id} revoked`, "ok");
    } catch (e) {
      toast(`revoke refused: ${e.message}`, "error");
    }
  }
}
